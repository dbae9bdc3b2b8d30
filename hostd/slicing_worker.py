"""Slicing in a separate process, so the event loop and the serial stream never stall.

One worker process (:class:`hostd.worker_process.WorkerProcess`: spawned, so it shares
nothing with the daemon's threads) imports the slicer; the daemon itself never imports numpy
or trimesh. Results are cached on disk by ``sha256(STL) + sha256(profile + slicer code)``
(:class:`hostd.slice_cache.SliceCache`): an upgraded slicer never serves G-code an older one
wrote. The slicer's refusals (walls over air, the head's collisions, no decomposition) are
kept the same way: the same file sent again is refused at once, not after the minute its
closed loop took.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import logging
import os
import shutil
import socket
import tempfile
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

from hostd.slice_cache import SliceCache
from hostd.stats import SLICE_BOUNDS, Buckets
from hostd.worker_process import WorkerDied, WorkerProcess

log = logging.getLogger(__name__)

PROFILE_SECTIONS = ("machine", "printhead", "process", "decompose")
"""Config sections that change the sliced output (and so the cache key)."""
CODE_PACKAGES = ("slicer", "kinematics")
CANCELLED = "slicing stopped: the job was cancelled"
"""Packages whose source changes the sliced output (and so the cache key)."""


class SliceError(Exception):
    """The model cannot be sliced (corrupt STL, too large, slicer failure)."""


class SliceRefused(SliceError):
    """The slicer refused the model after planning it (walls over air, a head collision, a
    layer in the air, no decomposition): the same STL, profile and code meet it again."""


@dataclass(frozen=True)
class SliceOptions:
    """What a job asks of its slice beyond the daemon's config.

    Attributes
    ----------
    allow_overhang : bool
        Keep a file whose replay finds unsupported wall layers (with a warning) instead of
        refusing it.
    decompose : dict of str to int
        ``seed`` and ``parts`` over ``decompose.seed`` / ``decompose.parts``.
    """

    allow_overhang: bool = False
    decompose: Mapping[str, int] = field(default_factory=dict)

    def config_values(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """``values`` (dotted config keys) with the decomposition settings asked for."""
        return {**values, **{f"decompose.{k}": v for k, v in self.decompose.items()}}

    def cache_profile(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """The profile keying the cache: a file let through with unsupported wall layers is
        never served to a job that did not ask for it."""
        profile = profile_of(self.config_values(values))
        return {**profile, "allow_overhang": True} if self.allow_overhang else profile


@dataclass(frozen=True)
class SliceOutcome:
    gcode_path: Path
    cache_hit: bool
    duration_s: float
    info: dict[str, Any]


def profile_of(values: Mapping[str, Any]) -> dict[str, Any]:
    """The slicing-relevant part of a config's dotted values."""
    return {k: v for k, v in sorted(values.items()) if k.split(".", 1)[0] in PROFILE_SECTIONS}


def cache_key(stl_sha: str, profile: Mapping[str, Any], code: str | None = None) -> str:
    """The cache entry of an STL (its sha256) sliced with ``profile`` by slicer ``code``
    (:func:`code_digest` by default)."""
    blob = json.dumps(profile, sort_keys=True, default=list).encode()
    digest = hashlib.sha256(blob)
    digest.update((code if code is not None else code_digest()).encode())
    return f"{stl_sha}-{digest.hexdigest()[:32]}"


@cache
def code_digest() -> str:
    """sha256 of the slicer's source (:data:`CODE_PACKAGES`, every ``.py`` by path), read
    once per process: a fix in the slicer makes every cached result a miss."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for package in CODE_PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode() + b"\0")
            digest.update(path.read_bytes())
    return digest.hexdigest()


OnProgress = Callable[[str, float], None]
"""``on_progress(stage, percent)`` of a slice (:data:`slicer.pipeline.STAGES`)."""
PROGRESS_BYTES = 512
"""Largest progress datagram read."""


class ProgressListener:
    """Where the worker tells a slice's stages: a Unix datagram socket in a directory of the
    daemon's own (mode 0700), read on the event loop as datagrams arrive."""

    def __init__(self, on_progress: OnProgress) -> None:
        self.on_progress = on_progress
        self._dir = tempfile.mkdtemp(prefix="hostd-slice-")
        self.path = os.path.join(self._dir, "progress")
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.bind(self.path)
        self._sock.setblocking(False)
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(self._sock.fileno(), self._read)

    def _read(self) -> None:
        while True:
            try:
                data = self._sock.recv(PROGRESS_BYTES)
            except OSError:  # BlockingIOError: nothing more now
                return
            try:
                msg = json.loads(data)
                stage, percent = str(msg["stage"]), float(msg["percent"])
            except (ValueError, KeyError, TypeError):
                continue
            self.on_progress(stage, percent)

    def close(self) -> None:
        self._loop.remove_reader(self._sock.fileno())
        self._sock.close()
        shutil.rmtree(self._dir, ignore_errors=True)


def progress_sender(path: str | None) -> OnProgress | None:
    """In the worker: a function that sends each stage to the listener at ``path`` (lost,
    never waited for, when the daemon does not read)."""
    if path is None:
        return None
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.setblocking(False)

    def send(stage: str, percent: float) -> None:
        with contextlib.suppress(OSError):
            sock.sendto(json.dumps({"stage": stage, "percent": percent}).encode(), path)

    return send


def slice_in_worker(stl_path: str, values: dict[str, Any], out_path: str,
                    name: str | None = None, allow_overhang: bool = False,
                    progress_path: str | None = None) -> dict[str, Any]:
    """Runs in the worker process: slice ``stl_path`` with config ``values`` to ``out_path``.

    An error is one line naming the upload as ``name`` (the operator's file name), not the
    spool file it is kept in, first. A file with unsupported wall layers is refused unless
    ``allow_overhang``; a refusal's advice names ``hostctl print``'s options.

    The G-code is written to a temporary name and renamed, so a crash never leaves a partial
    file under the cache key. Each stage is sent to the :class:`ProgressListener` at
    ``progress_path`` as it starts.
    """
    from hostd.config import convert
    from hostd.config.loader import Config
    from slicer.advice import PRINT_OPTIONS
    from slicer.gcode import write_gcode
    from slicer.pipeline import slice_model

    cfg = Config(values, "<daemon>")
    tmp = f"{out_path}.{os.getpid()}.tmp"
    try:
        result = slice_model(stl_path, allow_overhang=allow_overhang, knobs=PRINT_OPTIONS,
                             progress=progress_sender(progress_path), keep_plan=True,
                             **convert.slice_inputs(cfg))
        write_gcode(tmp, result.lines)
    except Exception as exc:  # the slicer's own errors, reported as one line to the operator
        Path(tmp).unlink(missing_ok=True)
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if name:
            text = text.replace(stl_path, name).replace(Path(stl_path).name, name)
            if not text.startswith(f"{name}: "):  # a refusal of the slicer's own
                text = f"{name}: {text}"
        kind = SliceRefused if isinstance(exc, refusals()) else SliceError
        raise kind(text) from None
    os.replace(tmp, out_path)
    return {**_summary(result), "pictures": draw_pictures(result.plan, out_path)}


def refusals() -> tuple[type[Exception], ...]:
    """In the worker: the slicer's errors that the same input meets again
    (:class:`SliceRefused`); a budget or a worker's death is not one of them."""
    from slicer.decompose import DecompositionError
    from slicer.pipeline import ReplayRefusal

    return (ReplayRefusal, DecompositionError)


PICTURES = ("decomposition", "toolpaths")
"""The pictures of a sliced job: its sub-parts with their cut planes and build order, and
its toolpaths by sub-part."""


def picture_path(gcode_path: str | Path, which: str) -> Path:
    """Where the picture ``which`` of the sliced G-code at ``gcode_path`` is kept."""
    return Path(gcode_path).with_suffix(f".{which}.png")


def draw_pictures(plan: Any, out_path: str) -> list[str]:
    """In the worker: the pictures of ``plan`` next to its G-code (:func:`picture_path`),
    the names of those drawn. A picture that cannot be drawn is left out (logged), never a
    failed slice."""
    from slicer.preview import render_preview, render_toolpaths

    drawn = []
    for which in PICTURES:
        try:
            if which == "toolpaths":
                render_toolpaths(plan, picture_path(out_path, which))
            elif plan.decomposition is not None:
                render_preview(plan.decomposition, picture_path(out_path, which))
            else:
                continue
        except Exception as exc:  # matplotlib's, or a plan it cannot draw
            log.warning("picture %s of %s not drawn: %s", which, out_path, exc)
            continue
        drawn.append(which)
    return drawn


def _summary(result: Any) -> dict[str, Any]:
    """Plain figures of a SliceResult for the job record."""
    est = result.estimate
    return {"subparts": int(result.subparts), "layers": int(result.layers),
            "transitions": len(result.transitions), "lines": len(result.lines),
            "filament_mm": float(est["filament_mm"]), "time_s": float(est["time_s"]),
            "replay": {k: v for k, v in result.replay.items()
                       if isinstance(v, int | float)},
            "merged_shells": int(result.merged_shells),
            "base_note": result.base_note, "seed": result.seed,
            "parts": result.parts,
            "unsupported_wall_layers": len(result.replay.get("unsupported_wall_layers", [])),
            "overhang_warning": result.warning}


def sliced_reason(info: dict[str, Any]) -> str:
    """The job's reason for READY after a slice: ``"sliced"``, the shells merged, the face
    the part was turned to stand on (or a much larger one it could stand on), and the
    unsupported wall layers let through (``--allow-overhang``)."""
    merged = int(info.get("merged_shells") or 0)
    parts = ["sliced"] + (
        [f"merged {merged} overlapping shells of the file into one solid"] if merged else [])
    note, warning = info.get("base_note"), info.get("overhang_warning")
    return "; ".join(parts + ([str(note)] if note else [])
                     + ([f"warning: {warning}"] if warning else []))


class SlicingWorker:
    """Slices STL files in a child process, with a result cache.

    Parameters
    ----------
    cache_dir
        Where sliced G-code is kept, named by cache key.
    values
        The daemon's config values (the profile part keys the cache).
    """

    def __init__(self, cache_dir: str | Path, values: Mapping[str, Any]) -> None:
        self.cache_dir = Path(cache_dir)
        self.cache = SliceCache(self.cache_dir)
        self.values = dict(values)
        self.profile = profile_of(self.values)
        self.code = code_digest()  # read once at start: never from disk on the event loop
        self.process = WorkerProcess()
        self.durations = Buckets(SLICE_BOUNDS)
        self.last_duration_s: float | None = None
        self.cache_hits = 0
        self.failures = 0
        self.active = 0
        self.cancelled = 0
        self._cancelling = False
        self._running = False  # a slice runs in the worker process (not a cache look-up)

    async def slice(self, stl_path: Path, stl_sha: str, name: str | None = None,
                    options: SliceOptions | None = None,
                    on_progress: OnProgress | None = None) -> SliceOutcome:
        """The G-code of the STL at ``stl_path`` (its sha256 ``stl_sha``) sliced as
        ``options`` ask, from the cache or sliced in the worker (each stage told to
        ``on_progress``); :class:`SliceError` naming the upload ``name``."""
        options = options or SliceOptions()
        key = cache_key(stl_sha, options.cache_profile(self.values), self.code)
        out = self.cache.gcode_path(key)
        self.active += 1  # from here a cancel counts: one during the look-up stops the slice
        self._cancelling = False
        try:
            info = await asyncio.to_thread(self.cache.lookup, key)
            if info is not None:
                self.cache_hits += 1
                return SliceOutcome(out, True, 0.0, info)
            if self._cancelling:
                raise SliceError(CANCELLED)
            await self._refused_before(key, name)
            if self._cancelling:  # during the refusal's look-up: the slice never starts
                raise SliceError(CANCELLED)
            started = time.monotonic()
            self._running = True
            try:
                info = await self._run(stl_path, out, name, options, on_progress)
            except SliceRefused as exc:
                await self._keep_refusal(key, str(exc), name)
                raise
        except WorkerDied:
            await asyncio.to_thread(self._discard, key, out)
            if self._cancelling:
                raise SliceError(CANCELLED) from None
            self.failures += 1
            raise SliceError("the slicing worker died (out of memory?)") from None
        except SliceError:
            if self._cancelling:  # what the ended slice said last (its STL deleted, ...)
                raise SliceError(CANCELLED) from None
            self.failures += 1
            raise
        finally:
            self.active -= 1
            self._running = False
        if self._cancelling:  # it returned as it was ended: nobody wants the file
            await asyncio.to_thread(self._discard, key, out)
            raise SliceError(CANCELLED)
        duration = time.monotonic() - started
        self.durations.observe(duration)
        self.last_duration_s = duration
        try:
            info = await asyncio.to_thread(self.cache.store, key, info)
        except OSError as exc:
            self.failures += 1
            raise SliceError(f"cannot keep the sliced G-code: {exc.strerror or exc}") from None
        return SliceOutcome(out, False, duration, info)

    def _discard(self, key: str, out: Path) -> None:
        """What a worker ended mid-slice left under ``key``: its partial G-code, or the
        G-code and pictures of a slice it finished as it was ended or cancelled (no info
        was kept for them: not a cache entry, and the job is gone)."""
        for tmp in out.parent.glob(f"{out.name}.*.tmp"):
            tmp.unlink(missing_ok=True)
        self.cache.remove(key)

    async def _refused_before(self, key: str, name: str | None) -> None:
        """Raise the slicer's refusal of ``key`` when it was kept, naming the upload
        ``name`` (a cache hit)."""
        kept = await asyncio.to_thread(self.cache.refusal, key)
        if kept is None:
            return
        text, was = kept
        self.cache_hits += 1
        if was and name and text.startswith(f"{was}: "):  # the line names its upload first
            text = f"{name}: {text.removeprefix(f'{was}: ')}"
        raise SliceRefused(text)

    async def _keep_refusal(self, key: str, text: str, name: str | None) -> None:
        """Keep a refusal for the next job with the same key (one that cannot be kept is
        logged: the job's own refusal stands)."""
        try:
            await asyncio.to_thread(self.cache.store_refusal, key, text, name)
        except OSError as exc:
            log.warning("slice cache: refusal %s not kept: %s", key, exc.strerror or exc)

    async def _run(self, stl_path: Path, out: Path, name: str | None, options: SliceOptions,
                   on_progress: OnProgress | None) -> dict[str, Any]:
        """:func:`slice_in_worker` in the worker, its stages told to ``on_progress``."""
        listener = None
        if on_progress is not None:
            try:
                listener = ProgressListener(on_progress)
            except OSError as exc:  # no progress is no reason not to slice
                log.warning("slice progress: %s", exc)
        try:
            return await self.process.run(slice_in_worker, str(stl_path),
                                          options.config_values(self.values), str(out), name,
                                          options.allow_overhang,
                                          None if listener is None else listener.path)
        finally:
            if listener is not None:
                listener.close()

    def cancel(self) -> bool:
        """Stop the slice running now (its job was cancelled): the worker is ended and the
        next slice starts a fresh one. Whether a slice was running."""
        if not self.active:
            return False
        self._cancelling = True
        self.cancelled += 1
        if self._running:  # else the slice stops before it starts
            self.process.kill()
        return True

    def close(self) -> None:
        self.process.close()

    def status(self) -> dict[str, Any]:
        return {"active": self.active, "durations": self.durations.snapshot(),
                "last_duration_s": self.last_duration_s, "cache_hits": self.cache_hits,
                "failures": self.failures, "cancelled": self.cancelled,
                "worker_started": self.process.started}
