"""A one-line description of the machine a figure was measured on (benchmarks, manifests, reports)."""

from __future__ import annotations

import os
import platform


def machine_description() -> str:
    """e.g. "2-core CPU (AMD EPYC 7B13), 24 GiB, no GPU" or "... , GPU NVIDIA H100 80GB HBM3"."""
    parts = [f"{os.cpu_count() or 1}-core CPU ({_cpu_model()})"]
    memory = _memory_gib()
    if memory:
        parts.append(f"{memory:.0f} GiB")
    try:
        import torch

        parts.append(f"GPU {torch.cuda.get_device_name(0)}" if torch.cuda.is_available() else "no GPU")
    except ImportError:
        pass
    return ", ".join(parts)


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as file:
            for line in file:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def _memory_gib() -> float | None:
    try:
        with open("/proc/meminfo") as file:
            for line in file:
                if line.startswith("MemTotal:"):
                    return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return None
