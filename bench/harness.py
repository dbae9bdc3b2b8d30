"""What the slicing benchmarks share: the model set and best-of-N timing.

The benches run as scripts (``python bench/NAME.py``), so this module is imported by its bare
name from the script's own folder.
"""

from __future__ import annotations

import argparse
import resource
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np
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


HARD = Path(__file__).resolve().parent.parent.parent / "shared" / "models" / "hard"


def finer(mesh: trimesh.Trimesh, faces: int) -> trimesh.Trimesh:
    """``mesh`` with exactly ``faces`` faces (or one more), the same surface.

    Each face is split 1 → 4 (``trimesh.Trimesh.subdivide``) while that stays within
    ``faces``, then the longest edges are halved (:func:`split_edges`) until the count is
    reached. A watertight mesh stays watertight; no vertex leaves the surface.
    """
    out = mesh.copy()
    while 4 * len(out.faces) <= faces:
        out = out.subdivide()
    while len(out.faces) < faces:
        out = split_edges(out, (faces - len(out.faces) + 1) // 2)
    return out


def split_edges(mesh: trimesh.Trimesh, count: int) -> trimesh.Trimesh:
    """Halve up to ``count`` of the longest interior edges, no two on one face.

    Each split edge gets its midpoint as a new vertex, and each of its two faces becomes two
    (same winding), so the mesh gains two faces an edge and stays conforming (no T-junction).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        (F, 3) faces; its edges shared by two faces are the candidates.
    count : int
        Most edges to split.

    Returns
    -------
    trimesh.Trimesh
        (F + 2k, 3) faces, k ≤ ``count`` the edges split.
    """
    pairs = mesh.face_adjacency  # (A, 2) faces sharing an edge
    edges = mesh.face_adjacency_edges  # (A, 2) its vertices
    length = np.linalg.norm(np.diff(mesh.vertices[edges], axis=1)[:, 0], axis=1)
    used = np.zeros(len(mesh.faces), dtype=bool)
    chosen = []
    for i in np.argsort(-length, kind="stable"):  # greedy: longest first, faces free
        a, b = pairs[i]
        if not (used[a] or used[b]):
            used[a] = used[b] = True
            chosen.append(i)
            if len(chosen) == count:
                break
    pick = np.asarray(chosen, dtype=int)
    mid = np.arange(len(pick)) + len(mesh.vertices)
    faces = mesh.faces
    split = pairs[pick].ravel()  # (2k,) faces, each with its edge's midpoint
    m = np.repeat(mid, 2)
    ends = np.repeat(edges[pick], 2, axis=0)
    tri = faces[split]
    # the corner off the edge, then the face's order from it: (c, p, q) with p → q the edge
    k = np.argmax((tri != ends[:, :1]) & (tri != ends[:, 1:]), axis=1)
    rows = np.arange(len(tri))[:, None]
    c, p, q = tri[rows, (k[:, None] + np.arange(3)) % 3].T
    halves = np.vstack([np.column_stack([c, p, m]), np.column_stack([c, m, q])])
    keep = np.ones(len(faces), dtype=bool)
    keep[split] = False
    vertices = np.vstack([mesh.vertices, mesh.vertices[edges[pick]].mean(axis=1)])
    return trimesh.Trimesh(vertices, np.vstack([faces[keep], halves]), process=False)


def hard_model(name: str, faces: int = 50_000) -> trimesh.Trimesh:
    """``shared/models/hard/NAME.stl`` made :func:`finer` to ``faces`` faces."""
    return finer(trimesh.load(HARD / f"{name}.stl", force="mesh"), faces)


MODELS: dict[str, Callable[[], trimesh.Trimesh]] = {
    "cylinder": samples.cylinder, "pipe2": samples.pipe2, "pipe3": samples.pipe3,
    "curved": samples.curved_pipe, "pipe3-50k": pipe3_50k}


def check_models(parser: argparse.ArgumentParser, names: list[str], hard: bool = False
                 ) -> list[str]:
    """``names`` (all models when empty), or a parser error naming the unknown ones; with
    ``hard``, ``h:NAME`` names are taken too (:func:`model_mesh`)."""
    unknown = {n for n in names if n not in MODELS and not (hard and n.startswith("h:"))}
    if unknown:
        parser.error(f"unknown model(s) {', '.join(sorted(unknown))}; choose from "
                     f"{', '.join(MODELS)}" + (" or h:NAME (shared/models/hard)" if hard
                                               else ""))
    return names or list(MODELS)


def model_mesh(name: str) -> trimesh.Trimesh:
    """A bench model by name, or for ``h:NAME`` the hard model NAME made 50 000 faces
    (:func:`hard_model`)."""
    return hard_model(name[2:]) if name.startswith("h:") else MODELS[name]()


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
