"""Study directories: refuse to resume with a configuration that would mix results."""

from __future__ import annotations

import json
from pathlib import Path


def guard_config(out: Path, cfg: dict, selection: tuple[str, ...] = (),
                 name: str = "config.json", advice: str = "use another --out") -> dict:
    """Write ``cfg`` to ``out/name``, or check it against the one already there.

    Fields in ``selection`` only choose *which* results are computed (run counts, the n or
    fold subsets, the device list) and are merged (lists: union; numbers: max); any other
    difference means the stored results came from another configuration, and resuming into
    that directory raises ``SystemExit`` naming the fields. A corrupt file is refused too.

    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> guard_config(d, {"images": 50, "ns": [6]}, ("ns",))["ns"]
    [6]
    >>> guard_config(d, {"images": 50, "ns": [9]}, ("ns",))["ns"]
    [6, 9]
    >>> guard_config(d, {"images": 20, "ns": [6]}, ("ns",))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    SystemExit: ... a different config (images: 50 there, 20 asked); use another --out
    """
    cfg = json.loads(json.dumps(cfg))
    path = out / name
    out.mkdir(parents=True, exist_ok=True)
    merged = dict(cfg)
    if path.exists():
        try:
            have = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise SystemExit(f"{path} is corrupt ({e}); {advice}") from None
        diff = sorted(k for k in set(have) | set(cfg)
                      if k not in selection and have.get(k) != cfg.get(k))
        if diff:
            what = ", ".join(f"{k}: {have.get(k)!r} there, {cfg.get(k)!r} asked" for k in diff)
            raise SystemExit(f"{out} holds a study with a different config ({what}); {advice}")
        for k in selection:
            a, b = have.get(k), cfg.get(k)
            if isinstance(a, list) and isinstance(b, list):
                union = a + [x for x in b if x not in a]
                numeric = all(isinstance(x, (int, float)) for x in union)
                merged[k] = sorted(union) if numeric else union
            elif isinstance(a, (int, float)) and isinstance(b, (int, float)):
                merged[k] = max(a, b)
    path.write_text(json.dumps(merged, indent=1))
    return merged
