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
