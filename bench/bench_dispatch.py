"""Dispatched tensor ops and host reads per tracked frame and per mapping step, renders excluded.

The SLAM runs on the pure-PyTorch kernels (``render.backend=torch``): on a GPU every op the
dispatcher sees there is at least one kernel launch, and every host read a synchronisation, so
these counts say on any machine what a frame costs a GPU in launches. Counted with a
``TorchDispatchMode`` after ``--warmup`` frames:

- a tracked frame: everything ``Slam.track`` dispatches, the map's renders left out;
- a mapping step (the second to the ``--steps + 1``-th of each counted frame's window): the ops
  between two steps of ``Slam.map``'s window, the render's forward and backward left out (the
  backward from the first gradient reaching a render's output to the end of ``backward()``:
  autograd runs every later node, the loss's, before any earlier one, the render's).

Host reads: ``item()`` / ``float()`` / ``bool()`` of a tensor, ops whose output size depends on the
data (``nonzero``, boolean indexing, ``unique``, ``masked_select``, ...), and ``tolist()`` / ``cpu()``
calls.

With ``--set render.compile=true`` the compiled graphs (the ICP, the mapping loss, Adam's update) run as
compiled while counted: a unit's count is then the ops they still dispatch (matrix products, solves,
allocations) plus every kernel Inductor generated for them that ran (each a launch, as its Triton
kernel would be on a GPU), counted by the profiler on the CPU.

    python bench/bench_dispatch.py [INPUT] [--downscale 2] [--frames 10] [--steps 8] [--warmup 8] [--set KEY=VALUE]
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import sys
import weakref
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch._inductor.config
from torch.utils._python_dispatch import TorchDispatchMode

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import append_section, command_line, commit, machine, markdown_table
from sgs_slam_core.cli.demo import default_room_dir, ensure_room
from sgs_slam_core.cli.run import default_preset
from sgs_slam_core.config import load_config
from sgs_slam_core.datasets import DatasetOptions, open_dataset
from sgs_slam_core.slam.system import Slam

# Ops that read the device's data on the host: a scalar read, or an output sized by the data.
HOST_READ_OPS = frozenset(
    {"_local_scalar_dense", "nonzero", "masked_select", "_unique", "_unique2", "unique_dim", "unique_consecutive",
     "unique_dim_consecutive", "repeat_interleave", "equal", "is_nonzero", "allclose", "masked_scatter"}
)  # fmt: skip
_BOOL_INDEXED = frozenset({"index", "index_put", "index_put_", "_index_put_impl_"})
# The profiler's annotations of compiled graphs (``record_function``): dispatched, but they launch nothing.
_ANNOTATIONS = frozenset({"_record_function_enter", "_record_function_enter_new", "_record_function_exit"})
# What the profiler calls Inductor's C++ kernels (``cpp.enable_kernel_profile``): graph_<n>_cpp_fused_<ops>
INDUCTOR_KERNEL = "cpp_fused"
# Tensor methods that bring a device's data to the host (neither dispatches on the CPU); ``numpy()`` is
# not one: on a GPU it needs a host tensor, so the ``cpu()`` before it was the read.
_TENSOR_READS = ("tolist", "cpu")


def _bool_index(args: tuple[Any, ...]) -> bool:
    """An index op given a boolean mask: its output size is the mask's count (a read on a GPU)."""
    indices = args[1] if len(args) > 1 and isinstance(args[1], (list, tuple)) else ()
    return any(isinstance(i, torch.Tensor) and i.dtype == torch.bool for i in indices)


class OpCounter(TorchDispatchMode):
    """Counts every dispatched op (by name) and the host reads among them while active and not paused."""

    def __init__(self) -> None:
        super().__init__()
        self.ops: Counter[str] = Counter()
        self.host_reads: Counter[str] = Counter()
        self.render_backward = 0  # ops left out as a render's backward
        self._paused = 0
        self._in_render_backward = False
        # storages a cpu() call brought over (reading them again is free), while its tensor lives
        self._host: dict[int, weakref.ref[torch.Tensor]] = {}

    def __torch_dispatch__(self, func: Any, types: Any, args: tuple[Any, ...] = (), kwargs: dict | None = None) -> Any:
        if self._in_render_backward:
            self.render_backward += 1
        elif not self._paused and func.overloadpacket.__name__ not in _ANNOTATIONS:
            name = func.overloadpacket.__name__
            self.ops[name] += 1
            if name in HOST_READ_OPS or (name in _BOOL_INDEXED and _bool_index(args)):
                self.host_reads[name] += 1
        return func(*args, **(kwargs or {}))

    @classmethod
    def ignore_compile_internals(cls) -> bool:
        """Compiled graphs run compiled while counted (else Dynamo runs them eagerly under a mode)."""
        return True

    @property
    def total(self) -> tuple[int, int]:
        """(ops, host reads) so far."""
        return sum(self.ops.values()), sum(self.host_reads.values())

    def render_backward_begins(self, grad: torch.Tensor) -> None:
        """A tensor hook on a render's outputs: what the running ``backward()`` still does is the render's."""
        self._in_render_backward = True

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """Nothing inside is counted."""
        self._paused += 1
        try:
            yield
        finally:
            self._paused -= 1

    def count_read(self, name: str, tensor: torch.Tensor) -> None:
        """A ``tolist()`` / ``cpu()`` of ``tensor``: a read unless an earlier ``cpu()`` brought its storage over."""
        storage = tensor.untyped_storage().data_ptr()
        brought = self._host.get(storage)
        if not self._paused and (brought is None or brought() is None):
            self.host_reads[name] += 1
        if name == "cpu":
            self._host[storage] = weakref.ref(tensor)

    @contextlib.contextmanager
    def active(self) -> Iterator[OpCounter]:
        """Count inside, ``Tensor.tolist`` / ``cpu`` calls included as host reads."""
        originals = {name: getattr(torch.Tensor, name) for name in _TENSOR_READS}

        def reader(name: str, method: Callable[..., Any]) -> Callable[..., Any]:
            def read(tensor: torch.Tensor, *args: Any, **kwargs: Any) -> Any:
                self.count_read(name, tensor)
                return method(tensor, *args, **kwargs)

            return read

        backward = torch.Tensor.backward

        def backward_then_count(tensor: torch.Tensor, *args: Any, **kwargs: Any) -> None:
            try:
                backward(tensor, *args, **kwargs)
            finally:
                self._in_render_backward = False

        for name, method in originals.items():
            setattr(torch.Tensor, name, reader(name, method))
        torch.Tensor.backward = backward_then_count  # type: ignore[method-assign]
        try:
            with self:
                yield self
        finally:
            for name, method in originals.items():
                setattr(torch.Tensor, name, method)
            torch.Tensor.backward = backward  # type: ignore[method-assign]


@contextlib.contextmanager
def compiled_kernels() -> Iterator[Counter[str]]:
    """Inductor's C++ kernels that ran inside, by name; filled when the block ends.

    Needs ``torch._inductor.config.cpp.enable_kernel_profile`` set before they compile.
    """
    ran: Counter[str] = Counter()
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        yield ran
    # the raw events: ``prof.events()`` builds a tree of every op first, seconds for a mapping step
    names = (event.name() for event in prof.profiler.kineto_results.events())
    ran.update(name for name in names if INDUCTOR_KERNEL in name)


@dataclass
class Counts:
    """Each counted unit's ops, host reads and render-backward ops left out, and the op names summed over the units."""

    ops: list[int] = field(default_factory=list)
    reads: list[int] = field(default_factory=list)
    render_backward: list[int] = field(default_factory=list)
    top: Counter[str] = field(default_factory=Counter)

    def row(self, what: str) -> list[object]:
        busiest = ", ".join(f"{name} {n / max(len(self.ops), 1):.0f}" for name, n in self.top.most_common(6))
        return [what, len(self.ops), f"{np.mean(self.ops):.0f}", f"{max(self.ops)}", f"{np.mean(self.reads):.1f}",
                f"{np.mean(self.render_backward):.0f}", busiest]  # fmt: skip


def _render_paused(slam: Slam, counter: OpCounter) -> None:
    """Leave the map's renders out of the counts: the forward, and the backward from its outputs on."""
    render = slam.kernels.render

    def paused_render(*args: Any, **kwargs: Any) -> Any:
        with counter.paused():
            out = render(*args, **kwargs)
        for channel in (out.color, out.depth, out.silhouette, out.semantic):
            if channel.requires_grad:
                channel.register_hook(counter.render_backward_begins)
        return out

    slam.kernels.render = paused_render  # type: ignore[method-assign]


@dataclass(frozen=True)
class Mark:
    """The counts at one point of a run."""

    total: tuple[int, int]  # (ops, host reads)
    ops: Counter[str]
    kernels: int  # compiled kernels run so far
    render_backward: int  # ops left out as renders' backward so far

    def to(self, later: Mark, unit: Counts) -> None:
        """Add what ran from here to ``later`` to ``unit``."""
        kernels = later.kernels - self.kernels
        unit.ops.append(later.total[0] - self.total[0] + kernels)
        unit.reads.append(later.total[1] - self.total[1])
        unit.top.update(later.ops - self.ops)
        unit.top["compiled kernel"] += kernels
        unit.render_backward.append(later.render_backward - self.render_backward)


def count_frame(slam: Slam, frame: Any, counter: OpCounter, track: Counts, steps: Counts, counted_steps: int) -> None:
    """Track and map ``frame``: its tracking count to ``track``, its first ``counted_steps`` whole steps' to ``steps``.

    Only the counted spans run under the profiler (its events of a mapping step, the render's
    included, take longer to read than the step to run).
    """
    marks: list[Mark] = []
    spans, ran = contextlib.ExitStack(), []  # one profile per counted span: its compiled kernels

    def mark() -> bool:
        spans.close()
        kernels = sum(sum(r.values()) for r in ran)
        marks.append(Mark(counter.total, counter.ops.copy(), kernels, counter.render_backward))
        if len(marks) < counted_steps + 4:  # before tracking, after it, before densifying, before step 2, ...
            ran.append(spans.enter_context(compiled_kernels()))
        return True

    with counter.active():
        mark()
        tracked = slam.track(frame)
        mark()
        slam.map(frame, tracked, mark)  # asks before densifying, then before each step but the first
        spans.close()
    marks[0].to(marks[1], track)
    for a, b in itertools.pairwise(marks[3 : counted_steps + 4]):  # from the second step on, whole steps
        a.to(b, steps)


def measure(args: argparse.Namespace) -> tuple[Counts, Counts]:
    """Run the SLAM, count ``--frames`` frames after ``--warmup``: (tracked frames, mapping steps)."""
    source = args.input or ensure_room(default_room_dir())
    dataset = open_dataset(source, options=DatasetOptions(downscale=args.downscale))
    overrides = ["render.backend=torch", "tracking.method=gauss_newton", *args.overrides]
    slam = Slam(load_config(args.preset or default_preset(source, "auto"), None, overrides))
    counter = OpCounter()
    _render_paused(slam, counter)
    track, steps = Counts(), Counts()
    last = min(args.warmup + args.frames, len(dataset))
    for i in range(last):
        if i < args.warmup:
            frame = dataset[i]
            slam.map(frame, slam.track(frame))
        else:
            count_frame(slam, dataset[i], counter, track, steps, args.steps)
    return track, steps


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input", type=Path, nargs="?", help="a dataset folder (default: the synthetic room)")
    p.add_argument("--downscale", type=float, default=2.0, help="the room is 320x240: 2 gives 160x120")
    p.add_argument("--preset", help="config preset (default: chosen from the dataset)")
    p.add_argument("--frames", type=int, default=10, help="frames counted")
    p.add_argument("--steps", type=int, default=8, help="mapping steps counted per frame (from its second on)")
    p.add_argument("--warmup", type=int, default=8, help="frames run before counting (the map and the motion model)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--no-append", action="store_true", help="print only; do not append to BENCHMARKS.md")
    args = p.parse_args()
    torch._inductor.config.cpp.enable_kernel_profile = True  # before anything compiles (``render.compile``)
    torch.manual_seed(0)
    track, steps = measure(args)
    headers = ["unit", "counted", "ops (mean)", "ops (max)", "host reads (mean)", "render backward left out (mean)",
               "busiest ops (per unit)"]  # fmt: skip
    rows = [track.row("tracked frame, renders left out"), steps.row("mapping step, its render left out")]
    text = markdown_table(headers, rows)
    print(text)
    if not args.no_append:
        note = f"{machine()}; {commit()}; `{command_line()}`"
        append_section("Dispatched ops and host reads", note + "\n\n" + text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
