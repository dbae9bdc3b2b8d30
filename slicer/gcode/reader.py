"""Read hostd G-code (or any G0/G1 file in G90 with M82/M83) into move arrays and headers.

Every ``G0``/``G1`` becomes one row with the pose it starts from and ends at; ``;HOSTD_*``
comment lines (:mod:`slicer.gcode.markers`) become headers (``KINEMATICS``, ``PROCESS``,
``PLACEMENT``, ``ESTIMATE``) and markers that tag the following moves with their sub-part,
layer and transition. Anything the reader cannot interpret raises :class:`GcodeFormatError`
naming the line.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from slicer.gcode.markers import (
    HEADERS,
    INTERFACE,
    LAYER,
    SUBPART,
    TRANSITION,
    TRANSITION_END,
    PayloadError,
    parse_marker,
    parse_payload,
    split_words,
)

AXES = "XYZAC"


class GcodeFormatError(ValueError):
    """A line the reader cannot interpret; the message starts with ``line N:``."""


@dataclass
class ParsedGcode:
    """Moves of a file as arrays, with headers and markers.

    Attributes
    ----------
    headers : dict
        Header name (``KINEMATICS`` …) to its JSON payload.
    start, end : (n, 5) float
        Pose [X, Y, Z, A, C] before/after each move; NaN where not yet known.
    e : (n,) float
        Relative filament of each move, mm.
    feed : (n,) float
        Feed, mm/s (NaN before the first F).
    g : (n,) int
        0 for G0, 1 for G1.
    line : (n,) int
        1-based line number of each move.
    subpart, layer : (n,) int
        From the latest ``HOSTD_SUBPART`` / ``HOSTD_LAYER`` markers (-1 before any).
    layer_seq : (n,) int
        Running count of layers in print order (-1 before the first layer).
    transition : (n,) bool
        Inside a ``HOSTD_TRANSITION`` … ``HOSTD_TRANSITION_END`` block.
    parents : dict of int to int or None
    interfaces : list of dict
        ``HOSTD_INTERFACE`` payloads with the layer_seq they precede.
    transitions : list of dict
        ``HOSTD_TRANSITION`` payloads with ``first``/``last`` move indices.
    """

    headers: dict[str, dict]
    start: np.ndarray
    end: np.ndarray
    e: np.ndarray
    feed: np.ndarray
    g: np.ndarray
    line: np.ndarray
    subpart: np.ndarray
    layer: np.ndarray
    layer_seq: np.ndarray
    transition: np.ndarray
    parents: dict[int, int | None] = field(default_factory=dict)
    interfaces: list[dict] = field(default_factory=list)
    transitions: list[dict] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.e)

    def require(self, name: str) -> dict:
        """A header's payload, or :class:`GcodeFormatError` if the file has none."""
        if name not in self.headers:
            raise GcodeFormatError(f"no ;HOSTD_{name} header: not a hostd five-axis file")
        return self.headers[name]


class _State:
    """Scalar parser state and the raw per-move columns."""

    def __init__(self) -> None:
        self.rel_e = True
        self.e_abs = 0.0
        self.sub, self.lay, self.seq, self.trans = -1, -1, -1, False
        self.vals: list[list[float]] = []  # X Y Z A C F per row (NaN: not given / unknown)
        self.home: list[bool] = []
        self.meta: list[tuple[float, int, int, int, int, int, bool]] = []
        self.headers: dict[str, dict] = {}
        self.parents: dict[int, int | None] = {}
        self.interfaces: list[dict] = []
        self.transitions: list[dict] = []
        self.blocks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # flushed rows
        self.flushed = 0

    def n_moves(self) -> int:
        """Rows so far (moves and homings)."""
        return self.flushed + len(self.meta)

    def flush(self) -> None:
        """Move the pending list rows into an array block."""
        if self.meta:
            self.add_block(np.asarray(self.vals, dtype=float).reshape(-1, 6),
                           np.asarray(self.home, dtype=bool),
                           np.asarray(self.meta, dtype=float).reshape(-1, 7))
            self.vals, self.home, self.meta = [], [], []

    def add_block(self, vals: np.ndarray, home: np.ndarray, meta: np.ndarray) -> None:
        """Append rows as arrays (after :meth:`flush`)."""
        self.blocks.append((vals, home, meta))
        self.flushed += len(meta)


_COLUMN = {"X": 0, "Y": 1, "Z": 2, "A": 3, "C": 4, "F": 5, "E": 6}
_MOVES = {"G0": 0, "G00": 0, "G1": 1, "G01": 1}


def _words(words: list[tuple[str, str]], n: int) -> dict[str, float]:
    out = {}
    for letter, value in words:
        try:
            out[letter.upper()] = float(value)
        except ValueError:
            raise GcodeFormatError(f"line {n}: bad word {letter + value!r}") from None
    return out


def _move(st: _State, words: list[tuple[str, str]], g: int, n: int) -> None:
    nan = float("nan")
    row = [nan, nan, nan, nan, nan, nan, nan]
    col = _COLUMN
    try:
        for letter, value in words:
            k = col.get(letter.upper())
            if k is not None:
                row[k] = float(value)
    except ValueError:
        raise GcodeFormatError(f"line {n}: bad word {letter + value!r}") from None
    e = row[6]
    if e != e:  # no E word
        e = 0.0
    elif not st.rel_e:
        e, st.e_abs = e - st.e_abs, e
    row[5] /= 60.0
    st.vals.append(row[:6])
    st.home.append(False)
    st.meta.append((e, g, n, st.sub, st.lay, st.seq, st.trans))


def _command(st: _State, body: str, n: int) -> None:
    head, words = split_words(body)
    head = head.upper()
    g = _MOVES.get(head)
    if g is not None:
        _move(st, words, g, n)
    elif head == "G91":
        raise GcodeFormatError(f"line {n}: G91 relative positioning is not supported")
    elif head in ("M82", "G90"):  # Marlin 2: G90 makes E absolute as well (after M83 too)
        st.rel_e = False
    elif head == "M83":
        st.rel_e = True
    elif head == "G92":
        values = _words(words, n)
        if set(values) - {"E"}:
            raise GcodeFormatError(f"line {n}: G92 of {''.join(sorted(set(values) - {'E'}))} "
                                   "is not supported (only E)")
        st.e_abs = values.get("E", 0.0)
    elif head == "G28":
        st.vals.append([float("nan")] * 6)
        st.home.append(True)
        st.meta.append((0.0, 0, n, st.sub, st.lay, st.seq, st.trans))


def _marker(st: _State, name: str, payload: str, n: int) -> None:
    try:
        data = parse_payload(payload)
    except PayloadError as exc:
        raise GcodeFormatError(f"line {n}: ;HOSTD_{name}: {exc}") from None
    try:
        _apply_marker(st, name, data, st.n_moves())
    except (KeyError, TypeError, ValueError) as exc:
        raise GcodeFormatError(f"line {n}: ;HOSTD_{name}: missing or bad key {exc}") from None


def _apply_marker(st: _State, name: str, data: dict, n_moves: int) -> None:
    if name in HEADERS:
        st.headers[name] = data
    elif name == SUBPART:
        st.sub, st.lay = int(data["index"]), -1
        parent = data.get("parent")
        st.parents[st.sub] = None if parent is None else int(parent)
    elif name == LAYER:
        st.sub, st.lay = int(data["subpart"]), int(data["index"])
        st.seq += 1
    elif name == INTERFACE:
        st.interfaces.append({**data, "layer_seq": st.seq})
    elif name == TRANSITION:
        st.trans = True
        st.transitions.append({**data, "first": n_moves, "last": n_moves - 1})
    elif name == TRANSITION_END:
        st.trans = False
        if st.transitions:
            st.transitions[-1]["last"] = n_moves - 1


def _fill(vals: np.ndarray, home: np.ndarray) -> np.ndarray:
    """Forward-fill each column; homing rows reset every axis to unknown."""
    resets = home[:, None] & (np.arange(vals.shape[1]) < len(AXES))[None, :]
    given = ~np.isnan(vals) | resets
    idx = np.where(given, np.arange(len(vals))[:, None], -1)
    idx = np.maximum.accumulate(idx, axis=0)
    padded = np.vstack([vals, np.full((1, vals.shape[1]), np.nan)])
    return padded[idx, np.arange(vals.shape[1])]


def _line(st: _State, raw: str, n: int) -> None:
    text = raw.strip()
    if not text:
        return
    if text[0] == ";":
        marker = parse_marker(text)
        if marker is not None:
            _marker(st, *marker, n)
        return
    body = text.split(";", 1)[0].strip()
    if body:
        _command(st, body, n)


def parse_lines(lines: Iterable[str]) -> ParsedGcode:
    """Parse G-code lines (with or without newlines)."""
    st = _State()
    for n, raw in enumerate(lines, start=1):
        _line(st, raw, n)
    return _assemble(st)


def _move_rows(st: _State, vals: np.ndarray, mask: np.ndarray, g1: np.ndarray, n: int) -> None:
    """Append k move lines given as printed values (k, 7: X Y Z A C E F), written-word mask
    and G1 flag, numbered from ``n + 1``: what :func:`_move` makes of their text."""
    k = len(vals)
    if k == 0:
        return
    row = np.where(mask[:, [0, 1, 2, 3, 4, 6]], vals[:, [0, 1, 2, 3, 4, 6]], np.nan)
    row[:, 5] /= 60.0
    e = np.where(mask[:, 5], vals[:, 5], 0.0)
    if not st.rel_e:
        given = np.flatnonzero(mask[:, 5])
        absolute = vals[given, 5]
        e[given] = absolute - np.r_[st.e_abs, absolute[:-1]]
        if len(given):
            st.e_abs = float(absolute[-1])
    meta = np.column_stack([e, g1, np.arange(n + 1, n + k + 1), np.full(k, st.sub),
                            np.full(k, st.lay), np.full(k, st.seq), np.full(k, st.trans)])
    st.flush()
    st.add_block(row, np.zeros(k, dtype=bool), meta.astype(float))


def parse_words(items: Iterable[str | tuple[np.ndarray, np.ndarray, np.ndarray]]
                ) -> ParsedGcode:
    """Parse a file given as raw lines and blocks of move lines already as numbers
    (:meth:`slicer.gcode.program.Program.words`): the same result as :func:`parse_lines` of
    its text, without formatting and re-reading the moves."""
    st = _State()
    n = 0
    for item in items:
        if isinstance(item, str):
            n += 1
            _line(st, item, n)
        else:
            _move_rows(st, *item, n)
            n += len(item[0])
    return _assemble(st)


def _assemble(st: _State) -> ParsedGcode:
    st.flush()
    vals = np.concatenate([b[0] for b in st.blocks] or [np.zeros((0, 6))])
    home = np.concatenate([b[1] for b in st.blocks] or [np.zeros(0, dtype=bool)])
    filled = _fill(vals, home)
    keep = ~home
    end = filled[keep, :5]
    before = np.vstack([np.full((1, 5), np.nan), filled[:-1, :5]])[keep]
    meta = np.concatenate([b[2] for b in st.blocks] or [np.zeros((0, 7))])[keep]
    kept_before = np.concatenate([[0], np.cumsum(keep)])
    for t in st.transitions:
        t["first"] = int(kept_before[t["first"]])
        t["last"] = int(kept_before[t["last"] + 1]) - 1
    return ParsedGcode(st.headers, before, end, meta[:, 0], filled[keep, 5],
                       meta[:, 1].astype(int), meta[:, 2].astype(int), meta[:, 3].astype(int),
                       meta[:, 4].astype(int), meta[:, 5].astype(int), meta[:, 6] > 0,
                       st.parents, st.interfaces, st.transitions)


def read_gcode(path: str | Path) -> ParsedGcode:
    """Parse a G-code file."""
    try:
        text = Path(path).read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError as exc:
        raise GcodeFormatError(f"{path}: not a text file ({exc.reason})") from None
    return parse_lines(text.splitlines())
