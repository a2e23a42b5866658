"""Occupancy grids in the ROS ``map_server`` format (an image + a YAML file) for the HSSH.

The YAML keys (ROS ``map_server``): ``image`` (path, relative to the YAML file), ``resolution``
(metres per cell), ``origin`` ``[x, y, yaw]`` (the pose of the lower-left cell), ``negate``
(0/1), ``occupied_thresh``, ``free_thresh`` and optional ``mode`` (``trinary`` — the default —,
``scale`` or ``raw``). A pixel value ``v`` of an 8-bit image gives ``p = (255 - v) / 255`` (or
``v / 255`` when ``negate``); ``p > occupied_thresh`` is occupied, ``p < free_thresh`` free and
anything between unknown (trinary). ``scale`` keeps the in-between cells as known with their
occupancy ``p`` (occupied iff ``p > occupied_thresh``); ``raw`` reads ``v`` as the occupancy
percentage (0..100, anything else unknown). Images: binary or ASCII PGM (``P5``/``P2``, 8 or 16
bit), or PNG through matplotlib.

Image row 0 is the top of the map (the largest y), as ROS draws it; :class:`OccupancyGrid`
keeps that orientation because the HSSH local levels index ``(row, col)`` images the same
way, and :meth:`OccupancyGrid.cell_of` / :meth:`OccupancyGrid.xy_of` convert between metres
and cells.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .arrays import DataError

__all__ = ["OccupancyGrid", "load_ros_map", "read_pgm", "write_ros_map"]

_MODES = ("trinary", "scale", "raw")


class OccupancyGrid(NamedTuple):
    """An occupancy grid read from a ROS map.

    occupied: ``[H, W]`` bool, True = occupied (the ``grid`` of ``hssh.local_topology``).
    unknown: ``[H, W]`` bool (its ``unknown``).
    probability: ``[H, W]`` float32 occupancy in ``[0, 1]``, NaN where unknown.
    resolution: cell side in metres.
    origin: ``(x, y, yaw)`` of the lower-left cell's corner.
    source: the YAML path it was read from.
    """

    occupied: np.ndarray
    unknown: np.ndarray
    probability: np.ndarray
    resolution: float
    origin: tuple[float, float, float]
    source: str

    def cell_of(self, xy) -> tuple[int, int]:
        """``(row, col)`` of the cell holding the world point ``xy`` (metres)."""
        x, y = (float(v) for v in xy)
        ox, oy, yaw = self.origin
        dx, dy = x - ox, y - oy
        c, s = math.cos(-yaw), math.sin(-yaw)
        u, v = c * dx - s * dy, s * dx + c * dy
        col = math.floor(u / self.resolution)
        row = self.occupied.shape[0] - 1 - math.floor(v / self.resolution)
        if not (0 <= row < self.occupied.shape[0] and 0 <= col < self.occupied.shape[1]):
            raise ValueError(f"xy {tuple(xy)} lies outside the map {self.source}")
        return row, col

    def xy_of(self, cell) -> tuple[float, float]:
        """World point (metres) of the centre of cell ``(row, col)``."""
        row, col = (float(v) for v in cell)
        u = (col + 0.5) * self.resolution
        v = (self.occupied.shape[0] - 1 - row + 0.5) * self.resolution
        ox, oy, yaw = self.origin
        c, s = math.cos(yaw), math.sin(yaw)
        return ox + c * u - s * v, oy + s * u + c * v


def _tokens(data: bytes, path: Path):
    """Header tokens of a PGM (comments skipped) and the offset after the last one."""
    out, i, n = [], 0, len(data)
    while len(out) < 4:
        while i < n and data[i:i + 1].isspace():
            i += 1
        if i < n and data[i:i + 1] == b"#":
            while i < n and data[i:i + 1] not in (b"\n", b"\r"):
                i += 1
            continue
        j = i
        while j < n and not data[j:j + 1].isspace() and data[j:j + 1] != b"#":
            j += 1
        if j == i:
            raise DataError(f"{path}: truncated PGM header")
        out.append(data[i:j].decode("ascii", "replace"))
        i = j
    return out, i + 1


def read_pgm(path: str | Path) -> np.ndarray:
    """A PGM image (``P5`` binary or ``P2`` ASCII, maxval <= 65535) as ``[H, W]`` uint8/uint16.

    Args:
        path: the ``.pgm`` file.

    Returns:
        [H, W] pixel values, top row first (uint8 for maxval < 256, else uint16).

    Raises:
        DataError: naming the file and the header field (missing file, magic, size,
            maxval, too few pixels).
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise DataError(f"{p}: image file not found") from None
    (magic, w, h, mx), off = _tokens(data, p)
    if magic not in ("P5", "P2"):
        raise DataError(f"{p}: header: magic {magic!r} is not a PGM (P5 or P2)")
    try:
        w, h, mx = int(w), int(h), int(mx)
    except ValueError:
        raise DataError(f"{p}: header: width/height/maxval must be integers") from None
    if w < 1 or h < 1 or not 0 < mx < 65536:
        raise DataError(f"{p}: header: bad size {w}x{h} or maxval {mx}")
    dt = np.dtype(np.uint8) if mx < 256 else np.dtype(">u2")
    if magic == "P5":
        need = w * h * dt.itemsize
        body = data[off:off + need]
        if len(body) < need:
            raise DataError(f"{p}: pixel data: {len(body)} bytes, header promises {need}")
        img = np.frombuffer(body, dt).reshape(h, w)
    else:
        try:
            vals = np.array(data[off:].split(), dtype=np.int64)
        except ValueError:
            raise DataError(f"{p}: pixel data: non-integer value in P2 image") from None
        if vals.size < w * h:
            raise DataError(f"{p}: pixel data: {vals.size} values, header promises {w * h}")
        img = vals[:w * h].reshape(h, w)
    if img.max(initial=0) > mx:
        raise DataError(f"{p}: pixel data: a value exceeds maxval {mx}")
    return img.astype(np.uint8 if mx < 256 else np.uint16)


def _read_yaml(path: Path) -> dict:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise DataError(f"{path}: file not found") from None
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a text (YAML) file") from None
    return _flat_yaml(text, path)


def _flat_yaml(text: str, path: Path) -> dict:
    """The flat YAML subset map_server reads and writes: ``key: value`` lines, ``[a, b, c]``
    lists, numbers and (optionally quoted) strings; ``#`` comments. No PyYAML needed."""
    d = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        if ":" not in line:
            raise DataError(f"{path}: line {n}: expected 'key: value'")
        k, v = (s.strip() for s in line.split(":", 1))

        def conv(s):
            s = s.strip().strip("'\"")
            try:
                return int(s)
            except ValueError:
                try:
                    return float(s)
                except ValueError:
                    return s
        d[k] = [conv(s) for s in v[1:-1].split(",")] if v.startswith("[") else conv(v)
    return d


def _number(d: dict, key: str, path: Path, lo=None, hi=None, default=None) -> float:
    if key not in d:
        if default is not None:
            return default
        raise DataError(f"{path}: missing key {key!r}")
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise DataError(f"{path}: key {key!r} must be a finite number, got {v!r}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise DataError(f"{path}: key {key!r} = {v} outside [{lo}, {hi}]")
    return float(v)


def load_ros_map(yaml_path: str | Path) -> OccupancyGrid:
    """Read a ROS ``map_server`` map (YAML + image) into an :class:`OccupancyGrid`.

    Errors (:class:`~pqrm_jax.io.DataError`) name the YAML or image file and the key or header
    field that is wrong (missing ``resolution``, ``origin`` not ``[x, y, yaw]``, NaN, a bad
    PGM magic number, too few pixels, ...).

    Args:
        yaml_path: the map's YAML file (its ``image`` is relative to it).

    Returns:
        :class:`OccupancyGrid` with the [H, W] occupied / unknown masks (row 0 = the top of
        the map, as the image), the occupancy probabilities, resolution and origin.

    Raises:
        DataError: naming the file and the key or header field.
    """
    p = Path(yaml_path)
    d = _read_yaml(p)
    if "image" not in d or not isinstance(d["image"], str) or not d["image"]:
        raise DataError(f"{p}: missing key 'image' (the image file, relative to the YAML)")
    res = _number(d, "resolution", p)
    if res <= 0:
        raise DataError(f"{p}: key 'resolution' must be > 0, got {res}")
    origin = d.get("origin")
    if (not isinstance(origin, list | tuple) or len(origin) != 3
            or not all(isinstance(v, int | float) and not isinstance(v, bool)
                       and math.isfinite(v) for v in origin)):
        raise DataError(f"{p}: key 'origin' must be [x, y, yaw] (finite numbers), got {origin!r}")
    occ_t = _number(d, "occupied_thresh", p, 0.0, 1.0)
    free_t = _number(d, "free_thresh", p, 0.0, 1.0)
    if free_t > occ_t:
        raise DataError(f"{p}: key 'free_thresh' ({free_t}) exceeds 'occupied_thresh' ({occ_t})")
    negate = d.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise DataError(f"{p}: key 'negate' must be 0 or 1, got {negate!r}")
    mode = d.get("mode", "trinary")
    if mode not in _MODES:
        raise DataError(f"{p}: key 'mode' must be one of {_MODES}, got {mode!r}")
    img_path = (p.parent / d["image"]) if not Path(d["image"]).is_absolute() else Path(d["image"])
    if img_path.suffix.lower() in (".pgm", ".pnm"):
        img = read_pgm(img_path)
        full = 255.0 if img.dtype == np.uint8 else 65535.0
        v = img.astype(np.float64)
    else:
        try:
            import matplotlib.image as mpimg
            arr = mpimg.imread(img_path)
        except FileNotFoundError:
            raise DataError(f"{img_path}: image file not found") from None
        except Exception as e:  # noqa: BLE001 - any decoder failure names the file
            raise DataError(f"{img_path}: unreadable image ({e})") from None
        arr = np.asarray(arr, np.float64)
        if arr.ndim == 3:
            arr = arr[..., :3].mean(axis=-1)  # map_server averages the colour channels
        full = 255.0
        v = arr * 255.0 if arr.max(initial=0) <= 1.0 else arr
    if mode == "raw":
        prob = np.where((v >= 0) & (v <= 100), v / 100.0, np.nan)
        unknown = np.isnan(prob)
        occupied = ~unknown & (prob > occ_t)
    else:
        prob = v / full if negate else (full - v) / full
        occupied = prob > occ_t
        if mode == "trinary":
            unknown = ~occupied & ~(prob < free_t)
        else:
            unknown = np.zeros_like(occupied)
        prob = np.where(unknown, np.nan, prob)
    return OccupancyGrid(occupied, unknown, prob.astype(np.float32), res,
                         tuple(float(x) for x in origin), str(p))


def write_ros_map(yaml_path: str | Path, occupied, unknown=None, *, resolution: float = 0.05,
                  origin=(0.0, 0.0, 0.0)) -> Path:
    """Write a trinary ROS map: ``NAME.yaml`` + ``NAME.pgm`` (0 occupied, 254 free, 205 unknown),
    the values and thresholds ``map_saver`` writes.

    Args:
        yaml_path: the YAML file to write (the image goes beside it with suffix ``.pgm``).
        occupied: [H, W] bool, occupied cells.
        unknown: [H, W] bool, unknown cells (None: none).
        resolution: metres per cell.
        origin: ``(x, y, yaw)`` of the lower-left cell.

    Returns:
        The YAML path written.

    Raises:
        ValueError: when ``occupied`` is not 2-D.
    """
    p = Path(yaml_path)
    occ = np.asarray(occupied, bool)
    if occ.ndim != 2:
        raise ValueError(f"occupied must be 2-D, got shape {occ.shape}")
    unk = np.zeros_like(occ) if unknown is None else np.asarray(unknown, bool)
    img = np.where(occ, 0, np.where(unk, 205, 254)).astype(np.uint8)
    pgm = p.with_suffix(".pgm")
    pgm.write_bytes(f"P5\n# written by pqrm-jax\n{occ.shape[1]} {occ.shape[0]}\n255\n".encode()
                    + img.tobytes())
    o = [float(v) for v in origin]
    p.write_text(f"image: {pgm.name}\nresolution: {float(resolution)}\n"
                 f"origin: [{o[0]}, {o[1]}, {o[2]}]\nnegate: 0\noccupied_thresh: 0.65\n"
                 "free_thresh: 0.196\nmode: trinary\n")
    return p
