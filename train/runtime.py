"""Device, precision, threads, torchrun ranks, and a dependency-free progress line."""
from __future__ import annotations

import contextlib
import os

import torch

from train.errors import TrainError

PRECISIONS = ("auto", "fp32", "bf16")


def pick_device(name: str = "auto") -> torch.device:
    """'auto' → CUDA when present (the local rank's GPU under torchrun), else CPU."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda":
        if not torch.cuda.is_available():
            raise TrainError("--device cuda: no CUDA device visible to torch")
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))
    if name != "cpu":
        raise TrainError(f"--device must be auto, cpu or cuda, got {name!r}")
    return torch.device("cpu")


def cpu_has_fast_bf16() -> bool:
    """True when the CPU computes bf16 natively (AMX or AVX512-BF16): then bf16 autocast ≈ 2× faster."""
    probes = ("_is_amx_tile_supported", "_is_avx512_bf16_supported")
    with contextlib.suppress(Exception):  # private torch probes; absent on some builds
        return any(getattr(torch.cpu, p)() for p in probes if hasattr(torch.cpu, p))
    return False


def autocast_dtype(device: torch.device, precision: str) -> torch.dtype | None:
    """bf16 for autocast on CUDA, and on CPUs with native bf16, when precision is auto; else None."""
    if precision not in PRECISIONS:
        raise TrainError(f"--precision must be one of {PRECISIONS}, got {precision!r}")
    if precision == "fp32":
        return None
    if precision == "bf16" or device.type == "cuda" or cpu_has_fast_bf16():
        return torch.bfloat16
    return None


def autocast(device: torch.device, dtype: torch.dtype | None) -> contextlib.AbstractContextManager:
    """torch.autocast for dtype, or a no-op when dtype is None."""
    if dtype is None:
        return contextlib.nullcontext()
    return torch.autocast(device.type, dtype=dtype)


def setup_threads(device: torch.device) -> None:
    """On CPU use every core for intra-op parallelism (torch may default to fewer); on CUDA autotune convs."""
    if device.type == "cpu":
        torch.set_num_threads(max(1, len(os.sched_getaffinity(0)) // world_size()))
    else:
        torch.backends.cudnn.benchmark = True  # one fixed input size: the fastest conv algorithm is found once


def world_size() -> int:
    """Processes in this torchrun job (1 outside torchrun)."""
    return int(os.environ.get("WORLD_SIZE", 1))


def rank() -> int:
    """This process's global rank (0 outside torchrun)."""
    return int(os.environ.get("RANK", 0))


def init_distributed(device: torch.device) -> None:
    """Join the torchrun process group (NCCL on CUDA, gloo on CPU) when WORLD_SIZE > 1."""
    import torch.distributed as dist

    if world_size() > 1 and not dist.is_initialized():
        if device.type == "cuda":
            torch.cuda.set_device(device)
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")


def barrier() -> None:
    """Wait for all ranks (no-op outside torchrun)."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        dist.barrier()


def mean_over_ranks(value: torch.Tensor) -> float:
    """A scalar averaged over all ranks (the value itself outside torchrun)."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        value = value.detach().clone()
        dist.all_reduce(value)
        value /= dist.get_world_size()
    return float(value)


def max_over_ranks(value: float) -> float:
    """The largest of a scalar over all ranks (the value itself outside torchrun)."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        t = torch.tensor(value, dtype=torch.float64)
        dist.all_reduce(t, op=dist.ReduceOp.MAX)
        return float(t)
    return value


def finish_distributed() -> None:
    """Leave the process group cleanly (no-op outside torchrun)."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()
