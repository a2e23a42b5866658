"""Save and load every map a user builds, with a format version; graphs to networkx / GraphML.

One file per map: a NumPy ``.npz`` (no pickle) holding the arrays and one JSON header,
``__header__``, with ``format`` = ``"pqrm-jax-map"``, ``format_version``, the map's ``kind``
(its class, e.g. ``pqrm_jax.pqrm.map.MapState``), the pqrm-jax version that wrote it and the
structure of the object. Supported: any NamedTuple of pqrm-jax (PQRM ``MapState``, ``QRMMap``,
Q-Link ``MapElements`` and ``LinkGraph``, HSSH ``LocalTopology`` with its skeleton tree, core
and gateways, ``MapHypothesis``) and the containers they hold (dict, list, tuple, set,
NumPy / JAX arrays, networkx graphs, numbers, strings, None). A JAX array comes back as a JAX
array with the same dtype, a NumPy array as NumPy; floats (inf, NaN included) bit for bit.

A file of a newer ``format_version``, of another ``kind`` than asked for, or damaged, raises
:class:`~pqrm_jax.io.DataError` naming the file and the field.
"""

from __future__ import annotations

import importlib
import json
import os
from pathlib import Path

import networkx as nx
import numpy as np

from .arrays import DataError

__all__ = ["MAP_FORMAT", "MAP_FORMAT_VERSION", "save_map", "load_map", "map_kind",
           "networkx_graph", "write_graphml"]

MAP_FORMAT = "pqrm-jax-map"
MAP_FORMAT_VERSION = 1


def _is_jax(x) -> bool:
    try:
        import jax
    except ImportError:  # pragma: no cover
        return False
    return isinstance(x, jax.Array)


def _encode(x, arrays: dict):
    if isinstance(x, np.generic):  # a NumPy scalar (np.float64 is also a float): 0-d array
        key = f"a{len(arrays)}"
        arrays[key] = np.asarray(x)
        return {"t": "scalar", "k": key}
    if x is None or isinstance(x, bool | str):
        return x
    if isinstance(x, int) and not isinstance(x, bool):
        return {"t": "int", "v": str(x)}
    if isinstance(x, float):
        return {"t": "float", "v": float(x).hex()}
    if isinstance(x, np.ndarray) or _is_jax(x):
        key = f"a{len(arrays)}"
        a = np.asarray(x)
        if a.dtype == object:
            raise TypeError("object arrays cannot be saved")
        arrays[key] = a
        return {"t": "array", "k": key, "jax": bool(_is_jax(x))}
    if isinstance(x, tuple) and hasattr(x, "_fields"):
        cls = type(x)
        name = f"{cls.__module__}.{cls.__qualname__}"
        if not cls.__module__.startswith("pqrm_jax."):
            raise TypeError(f"only pqrm-jax NamedTuples can be saved, got {name}")
        return {"t": "nt", "cls": name,
                "f": {f: _encode(getattr(x, f), arrays) for f in x._fields}}
    if isinstance(x, dict):
        return {"t": "dict", "items": [[_encode(k, arrays), _encode(v, arrays)]
                                       for k, v in x.items()]}
    if isinstance(x, list | tuple):
        return {"t": type(x).__name__, "v": [_encode(v, arrays) for v in x]}
    if isinstance(x, set | frozenset):
        items = sorted(x, key=repr)
        return {"t": type(x).__name__, "v": [_encode(v, arrays) for v in items]}
    if isinstance(x, nx.Graph):
        return {"t": "graph", "directed": x.is_directed(), "multi": x.is_multigraph(),
                "graph": _encode(dict(x.graph), arrays),
                "nodes": [[_encode(n, arrays), _encode(dict(a), arrays)]
                          for n, a in x.nodes(data=True)],
                "edges": [[_encode(u, arrays), _encode(v, arrays), _encode(dict(a), arrays)]
                          for u, v, a in x.edges(data=True)]}
    raise TypeError(f"cannot save a value of type {type(x).__name__}")


def _class(name: str, where: str):
    mod, _, qual = name.rpartition(".")
    if not mod.startswith("pqrm_jax."):
        raise DataError(f"{where}: refuses class {name!r} (only pqrm-jax NamedTuples load)")
    try:
        cls = getattr(importlib.import_module(mod), qual)
    except (ImportError, AttributeError):
        raise DataError(f"{where}: unknown class {name!r} (written by another pqrm-jax "
                        "version?)") from None
    if not (isinstance(cls, type) and issubclass(cls, tuple) and hasattr(cls, "_fields")):
        raise DataError(f"{where}: {name!r} is not a NamedTuple")
    return cls


def _decode(d, arrays, where: str):
    if d is None or isinstance(d, bool | str):
        return d
    if not isinstance(d, dict) or "t" not in d:
        raise DataError(f"{where}: malformed header entry {str(d)[:80]!r}")
    t = d["t"]
    if t == "int":
        return int(d["v"])
    if t == "float":
        return float.fromhex(d["v"])
    if t in ("array", "scalar"):
        if d["k"] not in arrays:
            raise DataError(f"{where}: array {d['k']!r} is missing")
        a = arrays[d["k"]]
        if t == "scalar":
            return a[()]
        if d["jax"]:
            import jax.numpy as jnp
            return jnp.asarray(a)
        return a
    if t == "nt":
        cls = _class(d["cls"], where)
        fields = d["f"]
        if set(fields) != set(cls._fields):
            raise DataError(f"{where}: {d['cls']} fields {sorted(fields)} do not match this "
                            f"pqrm-jax's {sorted(cls._fields)}")
        return cls(**{k: _decode(v, arrays, where) for k, v in fields.items()})
    if t == "dict":
        return {_decode(k, arrays, where): _decode(v, arrays, where) for k, v in d["items"]}
    if t in ("list", "tuple", "set", "frozenset"):
        vals = [_decode(v, arrays, where) for v in d["v"]]
        return {"list": list, "tuple": tuple, "set": set, "frozenset": frozenset}[t](vals)
    if t == "graph":
        cls = {(False, False): nx.Graph, (True, False): nx.DiGraph,
               (False, True): nx.MultiGraph, (True, True): nx.MultiDiGraph}[
            (d["directed"], d["multi"])]
        g = cls(**_decode(d["graph"], arrays, where))
        for n, a in d["nodes"]:
            g.add_node(_decode(n, arrays, where), **_decode(a, arrays, where))
        for u, v, a in d["edges"]:
            g.add_edge(_decode(u, arrays, where), _decode(v, arrays, where),
                       **_decode(a, arrays, where))
        return g
    raise DataError(f"{where}: unknown entry type {t!r}")


def save_map(path: str | Path, obj) -> Path:
    """Write ``obj`` (a map of any pqrm-jax system) to ``path`` (``.npz``) atomically.

    The file holds a JSON header (format, format version, kind, library version) and the
    map's arrays; :func:`load_map` reads it back equal.

    Args:
        path: the file to write; must end in ``.npz``.
        obj: a PQRM or QRM map, Q-Link elements or Link Graph, an HSSH local topology or map
            hypotheses (any NamedTuple / dataclass of arrays the format can hold).

    Returns:
        The path written.

    Raises:
        ValueError: when ``path`` does not end in ``.npz``, or ``obj`` holds something the
            format cannot store.

    >>> import tempfile, os, jax.numpy as jnp
    >>> from pqrm_jax import qrm
    >>> p = save_map(os.path.join(tempfile.mkdtemp(), "m.npz"), qrm.empty_map(4, "lr"))
    >>> m = load_map(p, kind="QRMMap")
    >>> type(m).__name__, m.rel.shape, m.rel.dtype
    ('QRMMap', (4, 4, 4), dtype('uint32'))
    """
    from .. import __version__

    p = Path(path)
    if p.suffix != ".npz":
        raise ValueError(f"path must end in .npz, got {str(p)!r}")
    arrays: dict = {}
    tree = _encode(obj, arrays)
    header = {"format": MAP_FORMAT, "format_version": MAP_FORMAT_VERSION,
              "kind": tree["cls"] if isinstance(tree, dict) and tree.get("t") == "nt"
              else type(obj).__name__, "pqrm_jax_version": __version__, "tree": tree}
    raw = np.frombuffer(json.dumps(header).encode(), np.uint8)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(f".{p.name}.tmp{os.getpid()}.npz")
    np.savez_compressed(tmp, __header__=raw, **arrays)
    os.replace(tmp, p)
    return p


def _open(path: Path):
    try:
        z = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise DataError(f"{path}: file not found") from None
    except (ValueError, OSError) as e:
        raise DataError(f"{path}: not a pqrm-jax map file (unreadable npz: {e})") from None
    with z:
        if "__header__" not in z.files:
            raise DataError(f"{path}: not a pqrm-jax map file (no '__header__')")
        try:
            header = json.loads(z["__header__"].tobytes().decode())
            arrays = {k: z[k] for k in z.files if k != "__header__"}
        except (ValueError, UnicodeDecodeError, OSError) as e:
            raise DataError(f"{path}: damaged file ({e})") from None
    if not isinstance(header, dict) or header.get("format") != MAP_FORMAT:
        raise DataError(f"{path}: field 'format' is {header.get('format')!r}, "
                        f"expected {MAP_FORMAT!r}")
    v = header.get("format_version")
    if not isinstance(v, int) or v < 1:
        raise DataError(f"{path}: field 'format_version' is {v!r}")
    if v > MAP_FORMAT_VERSION:
        raise DataError(f"{path}: field 'format_version' is {v}, newer than this pqrm-jax "
                        f"reads ({MAP_FORMAT_VERSION}); upgrade pqrm-jax")
    return header, arrays


def map_kind(path: str | Path) -> str:
    """The ``kind`` of a saved map (its class path) without loading its arrays' contents.

    Args:
        path: a file written by :func:`save_map`.

    Returns:
        The class path, e.g. ``"pqrm_jax.qrm.hypergraph.QRMMap"``.

    Raises:
        DataError: naming the file and the field when it is not a saved map of a known
            format version.
    """
    return _open(Path(path))[0]["kind"]


def load_map(path: str | Path, kind: str | None = None):
    """Load a map written by :func:`save_map`.

    Args:
        path: the ``.npz`` file.
        kind: when given, the class name (``"QRMMap"``) or full path the file must hold.

    Returns:
        The map, of the class it was saved from.

    Raises:
        DataError: naming the file and the field (not a saved map, an unknown format
            version, another ``kind`` than asked for).
    """
    p = Path(path)
    header, arrays = _open(p)
    got = header.get("kind", "")
    if kind is not None and kind not in (got, got.rpartition(".")[2]):
        raise DataError(f"{p}: field 'kind' is {got!r}, expected {kind!r}")
    return _decode(header.get("tree"), arrays, str(p))


def networkx_graph(obj, **kwargs) -> nx.Graph:
    """A networkx graph of a map: ``LinkGraph`` (elements via ``elements=``), ``MapHypothesis``
    (places; edge attributes ``gate`` and ``arrive``), ``LocalTopology`` (its pruned skeleton
    tree), or a graph returned unchanged.

    Args:
        obj: the map (or a networkx graph).
        **kwargs: ``elements=`` the Q-Link elements of a ``LinkGraph`` (node attributes).

    Returns:
        A ``networkx.Graph``.

    Raises:
        TypeError: for an object with no graph view.
    """
    if isinstance(obj, nx.Graph):
        return obj
    name = type(obj).__name__
    if name == "LinkGraph":
        from ..qlink import to_networkx as lg_nx
        return lg_nx(obj, kwargs.get("elements"))
    if name == "MapHypothesis":
        g = nx.Graph()
        for i, star in enumerate(obj.stars):
            g.add_node(i, star=str(tuple(zip(star.path, star.dir, star.alpha, strict=True))),
                       bearings=str(tuple(float(b) for b in obj.bearings[i])))
        for (p, e), (q, f) in obj.edges.items():
            g.add_edge(int(p), int(q), gate=int(e), arrive=int(f))
        return g
    if name == "LocalTopology":
        return obj.skeleton.tree.copy()
    raise TypeError(f"no graph view of a {name}")


def _graphml_value(v):
    if isinstance(v, bool | int | float | str):
        return v
    if isinstance(v, np.generic):
        return v.item()
    return json.dumps(np.asarray(v).tolist() if isinstance(v, np.ndarray) else v,
                      default=str)


def write_graphml(obj, path: str | Path, **kwargs) -> Path:
    """Write :func:`networkx_graph` of ``obj`` as GraphML (tuple nodes and non-scalar attributes
    become JSON strings, which GraphML can hold).

    Args:
        obj: the map (or a networkx graph).
        path: the ``.graphml`` file to write.
        **kwargs: passed to :func:`networkx_graph`.

    Returns:
        The path written.

    Raises:
        TypeError: for an object with no graph view.
    """
    g = networkx_graph(obj, **kwargs)
    h = g.__class__()
    h.graph.update({k: _graphml_value(v) for k, v in g.graph.items()})
    name = {n: (n if isinstance(n, int | str) else json.dumps(n, default=str)) for n in g}
    for n, a in g.nodes(data=True):
        h.add_node(name[n], **{k: _graphml_value(v) for k, v in a.items()})
    for u, v, a in g.edges(data=True):
        h.add_edge(name[u], name[v], **{k: _graphml_value(x) for k, x in a.items()})
    p = Path(path)
    nx.write_graphml(h, p)
    return p
