"""The three data sets of Padgett §3.4.1, simulated (docs/decisions.md §5).

* :func:`well_separated` — 49 landmarks whose Gaussian beliefs do not overlap (P Fig. 3.4);
* :func:`hallway` — a robot drives down a hallway observing wall landmarks; K landmark
  triplets are measured with Gaussian noise of variance 0.1 m² and normalised to the frame
  D=(0,0), E=(0,1) (eq. 3.11); each belief is 10 000 samples of F̂ (P Fig. 3.5);
* :func:`lab` — a lab-like room with 55 objects whose bounding-box centroids are tracked by a
  depth camera for a few seconds (the Kinect data of P Fig. 3.6 is not available; this scene
  stands in for it: objects on benches, shelves and the floor, a few close pairs, noise that
  grows with the distance to the sensor).

A :class:`Scene` holds the raw data points ``Z_k`` of every belief and builds beliefs from any
subset of them, which is what the 5-fold cross validation of P§3.4.1 needs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax
import numpy as np

from .beliefs import GaussianBeliefs, SampleBeliefs


def to_frame(d, e, f):
    """Coordinates of F in the frame D=(0,0), E=(0,1) (P eq. 3.11).

    Uses the calculus core's orientation (right of DE is α > 0): with v = E − D, w = F − D,
    α = (w × v)/|v|², β = (w · v)/|v|². (P's Γ_k as printed is a reflection; the core's frame
    is the orientation-preserving one, so SERGE QSRs and core calculi agree on sides.)

    Args:
        d: [..., 2] positions of D (NumPy or JAX).
        e: [..., 2] positions of E.
        f: [..., 2] positions of F.

    Returns:
        [..., 2] coordinates (α, β) of F.

    >>> to_frame(np.array([1., 1.]), np.array([1., 3.]), np.array([3., 1.])).tolist()
    [1.0, 0.0]
    """
    v = e - d
    w = f - d
    n = v[..., 0] ** 2 + v[..., 1] ** 2
    a = (w[..., 0] * v[..., 1] - w[..., 1] * v[..., 0]) / n
    b = (w[..., 0] * v[..., 0] + w[..., 1] * v[..., 1]) / n
    xp = jax.numpy if isinstance(a, jax.Array) else np
    return xp.stack([a, b], axis=-1)


def from_frame(d, e, p):
    """Inverse of :func:`to_frame`: world position of frame coordinates ``p`` [..., 2]."""
    v = e - d
    xp = jax.numpy if isinstance(v, jax.Array) else np
    right = xp.stack([v[..., 1], -v[..., 0]], axis=-1)
    return d + p[..., 0:1] * right + p[..., 1:2] * v


@dataclass
class Scene:
    """Raw data of K beliefs and how to turn a subset of it into beliefs.

    ``points[k]`` [S_k, 2] are the data points Z_k used for the error rate; ``kind`` is
    ``"gaussian"`` (beliefs fitted to the points) or ``"triplets"`` (beliefs sampled from the
    triplet measurements ``raw[k]`` [S_k, 3, 2] with noise ``noise_var``).
    """

    name: str
    points: list[np.ndarray]
    kind: str
    raw: list[np.ndarray] | None = None
    noise_var: float = 0.1
    n_samples: int = 10_000
    min_var: float = 0.0
    world: dict = field(default_factory=dict)

    @property
    def k(self) -> int:
        return len(self.points)

    def beliefs(self, subsets: list[np.ndarray] | None = None, key: jax.Array | None = None):
        """Beliefs from the data points with indices ``subsets[k]`` (all points by default)."""
        if subsets is None:
            subsets = [np.arange(len(p)) for p in self.points]
        if self.kind == "gaussian":
            return GaussianBeliefs.fit([p[s] for p, s in zip(self.points, subsets, strict=True)],
                                       min_var=self.min_var)
        key = jax.random.PRNGKey(0) if key is None else key
        rng = np.random.default_rng(np.asarray(jax.random.key_data(key)).ravel()[-1])
        out = np.empty((self.k, self.n_samples, 2), np.float32)
        for k, (r, s) in enumerate(zip(self.raw, subsets, strict=True)):
            t = rng.choice(np.asarray(s), self.n_samples)
            x = r[t] + rng.normal(0.0, np.sqrt(self.noise_var), (self.n_samples, 3, 2))
            out[k] = to_frame(x[:, 0], x[:, 1], x[:, 2])
        return SampleBeliefs(out)

    def folds(self, n_folds: int, seed: int = 0) -> list[np.ndarray]:
        """Fold index of every data point of every belief (balanced per belief)."""
        rng = np.random.default_rng(seed)
        return [rng.permutation(np.arange(len(p)) % n_folds) for p in self.points]


def well_separated(seed: int = 0, n_side: int = 7, spacing: float = 10.0, sd: float = 0.5,
                   n_points: int = 50) -> Scene:
    """49 landmarks on a jittered 7×7 lattice, ``sd`` ≪ spacing (P Fig. 3.4)."""
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(np.arange(n_side), np.arange(n_side), indexing="ij"), -1)
    centres = g.reshape(-1, 2) * spacing + rng.uniform(-0.1, 0.1, (n_side**2, 2)) * spacing
    pts = [c + rng.normal(0, sd, (n_points, 2)) * rng.uniform(0.6, 1.0, 2) for c in centres]
    return Scene("well_separated", pts, "gaussian", world={"landmarks": centres})


def hallway(seed: int = 0, n_triplets: int = 22, length: float = 40.0, width: float = 3.0,
            spacing: float = 4.0, sensor_range: float = 12.0, noise_var: float = 0.1,
            n_samples: int = 10_000, max_obs: int = 40) -> Scene:
    """The simulated hallway of P§3.4.1 (Fig. 3.5).

    Landmarks stand every ``spacing`` m on both walls (jittered); the robot drives down the
    centre line and at each pose measures every landmark within ``sensor_range`` in its own
    frame. Randomly drawn co-visible ordered triplets (D, E, F) give the raw data (one
    measurement per pose at which all three are visible) and their normalised F̂ the data
    points.

    Args:
        seed: seed of the layout, the triplets and the noise.
        n_triplets: number of co-visible ordered triplets drawn.
        length: hallway length (m).
        width: hallway width (m).
        spacing: landmark spacing along each wall (m).
        sensor_range: measurement range (m).
        noise_var: variance of the isotropic measurement noise N(0, ``noise_var``·I) (m²).
        n_samples: samples of F̂ per belief.
        max_obs: the most measurements kept per triplet.

    Returns:
        A :class:`Scene` of kind ``"triplets"``: the raw triplet measurements of each belief
        and its normalised data points.
    """
    rng = np.random.default_rng(seed)
    xs = np.arange(0.0, length + 1e-9, spacing)
    left = np.stack([xs + rng.uniform(-0.4, 0.4, len(xs)), np.full(len(xs), width / 2)], 1)
    right = np.stack([xs + spacing / 2 + rng.uniform(-0.4, 0.4, len(xs)),
                      np.full(len(xs), -width / 2)], 1)
    lm = np.concatenate([left, right])
    lm[:, 1] += rng.normal(0, 0.1, len(lm))
    poses = np.stack([np.linspace(-2, length + 2, 120), rng.normal(0, 0.2, 120),
                      rng.normal(0, 0.05, 120)], 1)
    vis = np.linalg.norm(lm[None] - poses[:, None, :2], axis=2) <= sensor_range   # (P, L)
    chosen: list[tuple[int, int, int]] = []
    while len(chosen) < n_triplets:
        p = rng.integers(len(poses))
        seen = np.flatnonzero(vis[p])
        if len(seen) < 3:
            continue
        tri = tuple(int(i) for i in rng.choice(seen, 3, replace=False))
        both = vis[:, list(tri)].all(axis=1)
        if both.sum() >= 10 and tri not in chosen:
            chosen.append(tri)
    raw, pts = [], []
    for tri in chosen:
        ps = np.flatnonzero(vis[:, list(tri)].all(axis=1))
        ps = np.sort(rng.choice(ps, min(max_obs, len(ps)), replace=False))
        meas = []
        for pi in ps:
            x, y, th = poses[pi]
            c, s = np.cos(th), np.sin(th)
            rel = (lm[list(tri)] - [x, y]) @ np.array([[c, -s], [s, c]])
            meas.append(rel + rng.normal(0, np.sqrt(noise_var), (3, 2)))
        meas = np.array(meas)
        raw.append(meas)
        pts.append(to_frame(meas[:, 0], meas[:, 1], meas[:, 2]))
    return Scene("hallway", pts, "triplets", raw=raw, noise_var=noise_var, n_samples=n_samples,
                 world={"landmarks": lm, "poses": poses, "triplets": np.array(chosen)})


def lab(seed: int = 0, n_objects: int = 55, size: tuple[float, float] = (9.0, 7.0),
        n_points: tuple[int, int] = (40, 90), noise_scale: float = 2.0,
        min_sep: float = 0.3) -> Scene:
    """A lab-like room with ``n_objects`` tracked objects (stand-in for P Fig. 3.6).

    Objects sit on benches along the walls, on two central tables and a few on the floor (some
    pairs only 0.3–0.5 m apart). A depth camera at the middle of the near wall tracks each object
    for a few seconds; centroid noise is anisotropic: ``noise_scale`` × (1.5 cm + 0.4 %·r² along
    the viewing ray, 1 cm + 0.2 %·r across it; r the range), plus a per-object bounding-box bias
    of sd ``noise_scale`` × 1.5 cm.

    Args:
        seed: seed of the layout and the noise.
        n_objects: number of objects.
        size: room size (m).
        n_points: ``[low, high)`` range of the number of tracked points per object.
        noise_scale: scale of the camera noise. The default 2 was chosen so that close objects
            overlap (|R| < μ at σ = 2 for large μ, as in P Fig. 3.7) without exceeding the
            published lab error level; it is a simulation choice, not data.
        min_sep: smallest distance between objects (m).

    Returns:
        A :class:`Scene` of kind ``"gaussian"``: the tracked points of each object, to which
        the beliefs are fitted.
    """
    rng = np.random.default_rng(seed)
    w, h = size
    objs: list[np.ndarray] = []

    def place(p, min_d):
        if all(np.linalg.norm(p - q) >= min_d for q in objs):
            objs.append(p)
            return True
        return False

    benches = [((-w / 2 + 0.4, -h / 2 + 1.0), (-w / 2 + 0.4, h / 2 - 0.4)),     # left wall
               ((-w / 2 + 1.0, h / 2 - 0.4), (w / 2 - 1.0, h / 2 - 0.4)),       # far wall
               ((w / 2 - 0.4, h / 2 - 0.4), (w / 2 - 0.4, -h / 2 + 1.0)),       # right wall
               ((-1.8, 0.2), (-0.4, 0.2)), ((0.6, 0.8), (2.0, 0.8))]            # tables
    while len(objs) < n_objects - 6:
        a, b = (np.array(x) for x in benches[rng.integers(len(benches))])
        place(a + rng.uniform() * (b - a) + rng.normal(0, 0.08, 2), min_sep)
    while len(objs) < n_objects:                                         # floor objects
        place(rng.uniform([-w / 2 + 1, -h / 2 + 1.2], [w / 2 - 1, h / 2 - 1.2]), 0.8)
    objs_a = np.array(objs)
    cam = np.array([0.0, -h / 2])
    pts = []
    for o in objs_a:
        d = o - cam
        r = np.linalg.norm(d)
        u = d / r
        v = np.array([-u[1], u[0]])
        sr, sc = noise_scale * (0.015 + 0.004 * r**2), noise_scale * (0.01 + 0.002 * r)
        n = rng.integers(*n_points)
        z = rng.normal(0, 1, (n, 2))
        bias = rng.normal(0, 0.015 * noise_scale, 2)
        pts.append(o + bias + z[:, :1] * sr * u + z[:, 1:] * sc * v)
    return Scene("lab", pts, "gaussian", min_var=1e-6, world={"objects": objs_a, "camera": cam})


SCENES = {"well_separated": well_separated, "hallway": hallway, "lab": lab}
