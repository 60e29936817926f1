"""The dispatch counter counts what it claims: every op, the host reads among them, nothing while paused."""

from __future__ import annotations

import torch
import torch._inductor.config

from bench.bench_dispatch import INDUCTOR_KERNEL, OpCounter, compiled_kernels


def test_counts_ops_and_host_reads():
    x = torch.arange(6.0)
    counter = OpCounter()
    with counter.active():
        y = (x * 2 + 1).sum()  # mul, add, sum: no read
        value = float(y)  # a scalar read
        picked = x[x > 2]  # gt, then indexing by a mask: its size is the data's
        listed = picked.tolist()  # a read that never reaches the dispatcher on the CPU
        host = (x * 2).cpu()  # a read ...
        again = host[1:].tolist()  # ... and its data already on the host: none
    assert value == 36.0 and listed == [3.0, 4.0, 5.0] and again == [2.0, 4.0, 6.0, 8.0, 10.0]
    assert counter.ops["mul"] == 2 and counter.ops["add"] == 1 and counter.ops["sum"] == 1 and counter.ops["gt"] == 1
    assert counter.host_reads["_local_scalar_dense"] == 1
    assert counter.host_reads["index"] == 1
    assert counter.host_reads["tolist"] == 1 and counter.host_reads["cpu"] == 1
    assert counter.total == (sum(counter.ops.values()), 4)


def test_nothing_is_counted_while_paused_or_after():
    x = torch.ones(4)
    counter = OpCounter()
    with counter.active(), counter.paused():
        _ = (x + 1).sum().item()
    _ = (x * 3).numpy()  # the methods are restored: no count outside
    assert counter.total == (0, 0)
    assert torch.Tensor.tolist.__name__ == "tolist"


def test_a_compiled_graph_runs_compiled_and_its_kernels_are_counted():
    def affine_sum(x: torch.Tensor) -> torch.Tensor:
        return (x * 2 + 1).sum()

    x = torch.arange(6.0)
    with torch._inductor.config.patch({"cpp.enable_kernel_profile": True}):
        compiled = torch.compile(affine_sum, dynamic=False)
        compiled(x)  # compiles outside the count
        counter = OpCounter()
        with counter.active(), compiled_kernels() as kernels:
            assert float(compiled(x)) == 36.0
    assert counter.ops["mul"] == 0 and counter.ops["add"] == 0  # the fused kernel, not the eager ops
    assert kernels.total() == 1 and all(INDUCTOR_KERNEL in name for name in kernels)
    assert counter.host_reads["_local_scalar_dense"] == 1


def test_a_renders_backward_is_left_out_and_counted_apart():
    x = torch.ones(4, requires_grad=True)
    counter = OpCounter()
    with counter.active():
        with counter.paused():  # the render's forward
            rendered = (x * 2).sigmoid()
        rendered.register_hook(counter.render_backward_begins)
        (rendered * 3).sum().backward()  # the loss's backward counted, then the render's left out
        after = x.grad + 1  # counted again once backward() returned
    assert float(after.sum()) > 4.0
    assert "sigmoid" not in counter.ops and "sigmoid_backward" not in counter.ops
    assert counter.render_backward >= 2  # sigmoid's backward and x * 2's, at least
    assert counter.ops["sum"] == 1 and counter.ops["add"] == 1 and counter.ops["mul"] >= 2
