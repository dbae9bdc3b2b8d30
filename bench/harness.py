"""What the slicing benchmarks share: the model set and best-of-N timing.

The benches run as scripts (``python bench/NAME.py``), so this module is imported by its bare
name from the script's own folder.
"""

from __future__ import annotations

import argparse
import resource
import time
from collections.abc import Callable
from typing import TypeVar

import trimesh

try:
    from slicer.mesh import samples
except ImportError:  # bench/ab_slice.py's other checkout, from before slicer/mesh/
    from slicer import samples

T = TypeVar("T")


def pipe3_50k(target: int = 50_000) -> trimesh.Trimesh:
    """pipe3 with finer circles, split 1 → 4 until it has about ``target`` faces."""
    mesh = samples.pipe3(segments=96)
    while len(mesh.faces) * 4 <= target * 1.5:
        mesh = mesh.subdivide()
    return mesh


MODELS: dict[str, Callable[[], trimesh.Trimesh]] = {
    "cylinder": samples.cylinder, "pipe2": samples.pipe2, "pipe3": samples.pipe3,
    "curved": samples.curved_pipe, "pipe3-50k": pipe3_50k}


def check_models(parser: argparse.ArgumentParser, names: list[str]) -> list[str]:
    """``names`` (all models when empty), or a parser error naming the unknown ones."""
    unknown = set(names) - set(MODELS)
    if unknown:
        parser.error(f"unknown model(s) {', '.join(sorted(unknown))}; choose from "
                     f"{', '.join(MODELS)}")
    return names or list(MODELS)


def cpu_seconds() -> float:
    """CPU seconds of this process and of its finished children (the slicer's worker
    processes)."""
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + kids.ru_utime + kids.ru_stime


def best_of(run: Callable[[], T], repeat: int) -> tuple[T, float, float]:
    """The fastest of ``repeat`` calls of ``run``: (result, wall s, CPU s with children)."""
    best: tuple[T, float, float] | None = None
    for _ in range(max(1, repeat)):
        wall, cpu = time.perf_counter(), cpu_seconds()
        result = run()
        timed = (result, time.perf_counter() - wall, cpu_seconds() - cpu)
        best = timed if best is None or timed[1] < best[1] else best
    assert best is not None
    return best
