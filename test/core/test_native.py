"""The compiled extensions: cache names (one per source text, flags, torch and CPU), and that they build."""

import shutil

import pytest

from sgs_slam_core.native import NativeExtension, prepare


def test_cache_name_follows_the_source_and_the_flags(tmp_path):
    src = tmp_path / "k.cpp"
    src.write_text("// one\n")
    ext = NativeExtension("k", src, "a kernel")
    first = ext.cache_name()
    assert first.startswith("sgs_slam_k_") and first == ext.cache_name()
    assert ext.cache_name(("-mno-avx512f",)) != first
    src.write_text("// two\n")  # another checkout's source, or an edit: never the old build
    assert ext.cache_name() != first


def test_a_missing_source_explains_itself(tmp_path):
    ext = NativeExtension("k", tmp_path / "absent.cpp", "a kernel")
    assert not ext.is_cached()
    assert not ext.is_available() and "a kernel" in ext.unavailable_reason()
    prepared = []
    prepare([ext], prepared.append)  # a failed build is not announced or tried again
    assert prepared == []


def test_a_cache_that_cannot_be_written_falls_back_with_a_reason(tmp_path, monkeypatch):
    """A read-only or broken TORCH_EXTENSIONS_DIR must not crash the run: the reference takes over."""
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("")
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(blocker / "ext"))
    src = tmp_path / "k.cpp"
    src.write_text("// cannot be built here\n")
    ext = NativeExtension("k", src, "a kernel")
    assert not ext.is_cached()
    assert not ext.is_available()
    assert "cannot build a kernel" in ext.unavailable_reason()
    assert "TORCH_EXTENSIONS_DIR" in ext.unavailable_reason()


@pytest.mark.skipif(shutil.which("g++") is None, reason="no C++ compiler")
def test_the_kernels_build_where_there_is_a_compiler():
    """The compiled tests skip when a build fails (a laptop without g++); here a failed build is a failure."""
    from sgs_slam_core.kernels.cpu.extensions import EXTENSIONS

    for ext in EXTENSIONS:
        assert ext.is_available(), ext.unavailable_reason()


class FakeLoad:
    """Stands in for torch's ``load``: records whether torch's build lock was there when it was called."""

    def __init__(self, build_root):
        self.build_root, self.calls = build_root, []

    def __call__(self, name, **_):
        self.calls.append((self.build_root / name / "lock").exists())
        return object()


def test_a_lock_left_by_a_killed_build_does_not_hang_the_next(tmp_path, monkeypatch):
    """torch waits forever on a ``lock`` file a killed build left; under our flock it can only be stale."""
    import torch.utils.cpp_extension as cpp

    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path / "ext"))
    src = tmp_path / "k.cpp"
    src.write_text("// k\n")
    ext = NativeExtension("k", src, "a kernel")
    name = ext.cache_name()
    (tmp_path / "ext" / name).mkdir(parents=True)
    (tmp_path / "ext" / name / "lock").write_text("")
    fake = FakeLoad(tmp_path / "ext")
    monkeypatch.setattr(cpp, "load", fake)
    assert ext.is_available(), ext.unavailable_reason()
    assert fake.calls == [False]


def test_a_build_under_way_in_another_process_is_waited_for(tmp_path, monkeypatch):
    import fcntl
    import os
    import threading

    import torch.utils.cpp_extension as cpp

    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path / "ext"))
    src = tmp_path / "k.cpp"
    src.write_text("// k\n")
    ext = NativeExtension("k", src, "a kernel")
    build_dir = tmp_path / "ext" / ext.cache_name()
    build_dir.mkdir(parents=True)
    (build_dir / "lock").write_text("")  # the other builder's torch lock, live while it holds the flock
    fake = FakeLoad(tmp_path / "ext")
    monkeypatch.setattr(cpp, "load", fake)
    fd = os.open(build_dir / "sgs_slam_build.flock", os.O_RDWR | os.O_CREAT)  # its own open file: another holder
    fcntl.flock(fd, fcntl.LOCK_EX)
    worker = threading.Thread(target=ext.is_available)
    try:
        worker.start()
        worker.join(0.5)
        assert worker.is_alive() and fake.calls == [] and (build_dir / "lock").exists()
        (build_dir / "lock").unlink()  # the other build finishes: torch removes its lock, then the flock goes
    finally:
        os.close(fd)
    worker.join(10)
    assert not worker.is_alive() and fake.calls == [False]


def test_two_checkouts_never_share_a_cache_entry(tmp_path):
    """torch's build files name the source's path: a shared entry would be rebuilt by each checkout in turn."""
    names = []
    for checkout in ("a", "b"):
        src = tmp_path / checkout / "k.cpp"
        src.parent.mkdir()
        src.write_text("// the same text\n")
        names.append(NativeExtension("k", src, "a kernel").cache_name())
    assert names[0] != names[1]
