"""Multi-process studies on JAX's distributed runtime (``jax.distributed``).

A study runs as N cooperating processes (one host or many): each process computes only its
share of the run axis on its local devices, the shares are gathered with JAX collectives
(gloo on CPU) and process 0 alone writes the results through the study store, so no two
processes write one file. A study adopts it in a few lines::

    cluster = distributed.initialize_from(args)    # before any other JAX call
    distributed.agree(cluster, config_json)         # refuse processes with other configs
    mine = distributed.share(n_items, cluster)      # indices this process computes
    parts = distributed.gather(local_results, cluster)  # [num_processes, ...] everywhere
    if cluster.is_main: ...write...

A study whose work is an array split (chunks of runs whose results are numpy arrays of one
shape per chunk) uses :func:`map_chunks`, which does the share, the padding to equal shapes,
the gather and the reordering in one call::

    results = distributed.map_chunks(compute_chunk, n_chunks, cluster)  # every process

A study whose units are independent records (one file or line each) uses the two
higher-level helpers instead, which keep its per-unit resume::

    left = distributed.decide(cluster, len(units), units_left)  # process 0 reads the store
    for i, rec in distributed.map_units(compute, [u for u, l in zip(units, left) if l],
                                        cluster, codec="npz"):
        if cluster.is_main: ...write rec...                    # unit by unit, in order

Where the process count, id and coordinator come from, first match wins:

1. the arguments (``--coordinator HOST:PORT --processes N --process-id I``);
2. the environment: ``JAX_COORDINATOR_ADDRESS`` (JAX's own variable), ``JAX_NUM_PROCESSES``,
   ``JAX_PROCESS_ID``;
3. Slurm (inside ``srun``, more than one task): the count and id from ``SLURM_NTASKS`` and
   ``SLURM_PROCID``, and JAX's own Slurm detection derives the coordinator from the node list
   and job id (then JAX's timeout applies: after ``timeout_s`` JAX ends the process with a
   fatal ``DEADLINE_EXCEEDED`` log line instead of our message);
4. none of these: one process, and ``jax.distributed`` is not started.

Bad input is refused before anything is computed: a process count below 1, an id outside
``0 <= I < N``, a malformed address (``ValueError``); an unreachable coordinator ends with a
:class:`DistributedError` after ``timeout_s`` seconds (``--init-timeout``, default 60), never a
hang; a process whose configuration differs from process 0's is refused on every process
(:func:`agree`).

Bit-identity with one process: every process runs the same compiled program on the same
per-device batches as a one-process run would (the split is over whole work items, e.g.
padgett-mc's chunks, never inside one), so the gathered results equal the one-process results
bit for bit; the process count is therefore not part of a study's stored configuration.

>>> c = initialize(num_processes=1, process_id=0, env={})
>>> (c.process_id, c.num_processes, c.is_main)
(0, 1, True)
>>> share(5, Cluster(1, 2, "127.0.0.1:1234"))
[1, 3]
>>> initialize(num_processes=2, process_id=2, coordinator="127.0.0.1:1234", env={})
Traceback (most recent call last):
...
ValueError: process id 2 is out of range for 2 processes (need 0 <= id < 2)
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

__all__ = ["Cluster", "DistributedError", "add_arguments", "agree", "broadcast", "current",
           "decide", "finish", "gather", "initialize", "initialize_from", "map_chunks",
           "map_units", "share"]

_ADDRESS = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.\-]+):(\d{1,5})$")


_STARTED: dict[str, str | None] = {}  # the coordinator address this process connected to


class DistributedError(RuntimeError):
    """The distributed runtime could not be started or the processes disagree."""


class Cluster(NamedTuple):
    """Where this process stands: its id, the process count and the coordinator address."""

    process_id: int
    num_processes: int
    coordinator: str | None

    @property
    def is_main(self) -> bool:
        """Process 0: the one that writes results."""
        return self.process_id == 0

    @property
    def distributed(self) -> bool:
        return self.num_processes > 1


def add_arguments(parser) -> None:
    """The ``--coordinator``, ``--processes``, ``--process-id``, ``--init-timeout`` flags."""
    g = parser.add_argument_group("multi-process (jax.distributed; README 'Running on a "
                                  "cluster')")
    g.add_argument("--coordinator", metavar="HOST:PORT",
                   help="address of process 0 (default: $JAX_COORDINATOR_ADDRESS, Slurm)")
    g.add_argument("--processes", dest="num_processes", type=int, metavar="N",
                   help="process count (default: $JAX_NUM_PROCESSES, Slurm, else 1)")
    g.add_argument("--process-id", type=int, metavar="I",
                   help="this process's id, 0 <= I < N (default: $JAX_PROCESS_ID, Slurm)")
    g.add_argument("--init-timeout", type=int, default=60, metavar="S",
                   help="seconds to wait for all processes to connect (default 60)")


def _int_env(env: Mapping[str, str], name: str) -> int | None:
    raw = env.get(name)
    if raw in (None, ""):
        return None
    try:
        return int(raw)
    except ValueError:
        raise ValueError(f"${name} must be an integer, got {raw!r}") from None


_SLURM = ("SLURM_JOB_ID", "SLURM_STEP_NODELIST", "SLURM_NTASKS", "SLURM_PROCID",
          "SLURM_LOCALID")  # the variables JAX's Slurm detection reads (inside ``srun``)


def _slurm(env: Mapping[str, str]) -> bool:
    try:
        return all(v in env for v in _SLURM) and int(env["SLURM_NTASKS"]) > 1
    except ValueError:
        return False


def initialize(coordinator: str | None = None, num_processes: int | None = None,
               process_id: int | None = None, *, timeout_s: int = 60,
               heartbeat_s: int = 60, env: Mapping[str, str] | None = None) -> Cluster:
    """Start ``jax.distributed`` for this process (see the module docstring for the sources).

    Must run before any JAX computation in the process (JAX's own rule). On CPU the
    collectives use gloo. Returns the :class:`Cluster`; with one process nothing is started.
    """
    env = os.environ if env is None else env
    coordinator = coordinator or env.get("JAX_COORDINATOR_ADDRESS") or None
    slurm = _slurm(env)
    if num_processes is None:
        num_processes = _int_env(env, "JAX_NUM_PROCESSES")
        if num_processes is None and slurm:
            num_processes = _int_env(env, "SLURM_NTASKS")
    if process_id is None:
        process_id = _int_env(env, "JAX_PROCESS_ID")
        if process_id is None and slurm:
            process_id = _int_env(env, "SLURM_PROCID")
    if timeout_s is None or int(timeout_s) < 1:
        raise ValueError(f"the initialization timeout must be >= 1 s, got {timeout_s}")
    explicit = (coordinator, num_processes, process_id)
    if all(v is None for v in explicit):
        return Cluster(0, 1, None)
    if num_processes is not None and (isinstance(num_processes, bool)
                                      or int(num_processes) != num_processes
                                      or num_processes < 1):
        raise ValueError(f"the process count must be an integer >= 1, got {num_processes}")
    if num_processes == 1 and process_id in (None, 0):
        return Cluster(0, 1, None)
    if process_id is not None and num_processes is not None and not (
            0 <= process_id < num_processes):
        raise ValueError(f"process id {process_id} is out of range for {num_processes} "
                         f"processes (need 0 <= id < {num_processes})")
    if not slurm and None in explicit:
        missing = [n for n, v in zip(("coordinator address (--coordinator or "
                                      "$JAX_COORDINATOR_ADDRESS)",
                                      "process count (--processes or $JAX_NUM_PROCESSES)",
                                      "process id (--process-id or $JAX_PROCESS_ID)"),
                                     explicit, strict=True) if v is None]
        raise ValueError("a multi-process run needs " + ", ".join(missing))
    if coordinator is not None:
        m = _ADDRESS.match(coordinator)
        if not m or not 0 < int(m.group(2)) < 65536:
            raise ValueError(f"the coordinator address must be HOST:PORT with a port in "
                             f"1..65535, got {coordinator!r}")
    import jax

    if coordinator is not None and process_id is not None and num_processes is not None:
        _rendezvous(coordinator, num_processes, process_id, float(timeout_s))
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    try:
        jax.distributed.initialize(coordinator, num_processes, process_id,
                                   initialization_timeout=int(timeout_s),
                                   heartbeat_timeout_seconds=int(heartbeat_s))
    except (ValueError, TypeError):
        raise
    except Exception as exc:  # XlaRuntimeError (DEADLINE_EXCEEDED, UNAVAILABLE, ...)
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DistributedError(
            f"could not start jax.distributed as process {process_id} of {num_processes} with "
            f"coordinator {coordinator} within {timeout_s} s (is process 0 running and the "
            f"port reachable? all N processes started?): {first[:300]}") from exc
    _STARTED["coordinator"] = coordinator
    cluster = current()
    # the first collective builds the collectives' context (gloo gives it 30 s to find every
    # peer; later collectives wait as long as needed): build it now, while every process is
    # here, not when one process is still compiling or reading the store
    gather(np.zeros(1, np.int32), cluster)
    return cluster


def _rendezvous(coordinator: str, n: int, pid: int, timeout_s: float) -> None:
    """Meet on the coordinator's port before JAX does, so that failures get clear errors.

    JAX's client ends the process with a fatal log line (no exception) when the coordinator
    or a peer never comes; here process 0 listens on the port until every id ``1..N-1`` has
    said hello (two processes claiming one id are refused), each peer retries connecting until
    ``timeout_s``, then process 0 answers and closes the port for JAX's own service.
    """
    import socket
    import struct
    import time

    host, port = coordinator.rsplit(":", 1)
    host, port = host.strip("[]"), int(port)
    deadline = time.monotonic() + timeout_s
    if pid == 0:
        try:
            srv = socket.create_server(("", port), reuse_port=False)
        except OSError as exc:
            raise DistributedError(f"process 0 cannot listen on port {port} of {coordinator} "
                                   f"({exc.strerror or exc}); choose a free port") from exc
        peers: dict[int, socket.socket] = {}
        try:
            while len(peers) < n - 1:
                left = deadline - time.monotonic()
                if left <= 0:
                    missing = sorted(set(range(1, n)) - set(peers))
                    raise DistributedError(
                        f"process 0 waited {timeout_s:g} s on {coordinator} but processes "
                        f"{missing} of {n} never connected (started? same --coordinator?)")
                srv.settimeout(left)
                try:
                    conn, _ = srv.accept()
                except TimeoutError:
                    continue
                conn.settimeout(max(deadline - time.monotonic(), 0.1))
                try:
                    their_id, their_n = struct.unpack("!ii", conn.recv(8, socket.MSG_WAITALL))
                except (OSError, struct.error):
                    conn.close()
                    continue
                problem = (f"process count {their_n} differs from process 0's {n}"
                           if their_n != n else
                           f"id {their_id} is out of range" if not 0 < their_id < n else
                           f"id {their_id} is claimed by two processes"
                           if their_id in peers else "")
                if problem:
                    conn.sendall(b"E")
                    conn.close()
                    for c in peers.values():
                        c.sendall(b"E")
                    raise DistributedError(f"refused a process on {coordinator}: {problem}")
                peers[their_id] = conn
            # a second port for the watch channels (the coordinator's port goes to JAX)
            watch_srv = socket.create_server(("", 0))
            watch_port = watch_srv.getsockname()[1]
            for c in peers.values():
                c.sendall(b"K" + struct.pack("!i", watch_port))
        finally:
            for c in peers.values():
                c.close()
            srv.close()
        try:
            chans: dict[int, socket.socket] = {}
            while len(chans) < n - 1:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise DistributedError(f"processes {sorted(set(range(1, n)) - set(chans))} "
                                           "did not open their watch channel to process 0")
                watch_srv.settimeout(left)
                try:
                    conn, _ = watch_srv.accept()
                    conn.settimeout(max(deadline - time.monotonic(), 0.1))
                    (their_id,) = struct.unpack("!i", conn.recv(4, socket.MSG_WAITALL))
                except (OSError, struct.error):
                    continue
                conn.settimeout(None)
                chans[their_id] = conn
        finally:
            watch_srv.close()
        _WATCH.start(0, n, chans)
        return
    while True:
        try:
            conn = socket.create_connection((host, port), timeout=1.0)
            break
        except OSError as exc:
            if time.monotonic() >= deadline:
                raise DistributedError(
                    f"process {pid} could not reach the coordinator {coordinator} within "
                    f"{timeout_s:g} s ({exc.strerror or exc}); start process 0 there, or fix "
                    f"--coordinator / $JAX_COORDINATOR_ADDRESS") from exc
            time.sleep(0.2)
    try:
        conn.settimeout(max(deadline - time.monotonic(), 1.0))
        conn.sendall(struct.pack("!ii", pid, n))
        answer = conn.recv(1)
        if answer == b"K":
            (watch_port,) = struct.unpack("!i", conn.recv(4, socket.MSG_WAITALL))
    except (OSError, struct.error) as exc:
        raise DistributedError(f"process {pid}: the coordinator {coordinator} did not confirm "
                               f"within {timeout_s:g} s ({exc})") from exc
    finally:
        conn.close()
    if answer != b"K":
        raise DistributedError(f"process {pid} was refused by the coordinator {coordinator} "
                               "(another process has this id, or the process counts differ; "
                               "see process 0's error)")
    try:
        chan = socket.create_connection((host, watch_port),
                                        timeout=max(deadline - time.monotonic(), 1.0))
        chan.sendall(struct.pack("!i", pid))
        chan.settimeout(None)
    except OSError as exc:
        raise DistributedError(f"process {pid} could not open its watch channel to process 0 "
                               f"on {host}:{watch_port} ({exc})") from exc
    _WATCH.start(pid, n, {0: chan})


class _Watch:
    """Every process of a run watches its peers, so that one dying ends the others quickly.

    Process 0 holds a TCP channel to every other process (opened at the rendezvous, on a
    port of its own); each side reads its channels in daemon threads. A channel closing
    without a goodbye (the process was killed, crashed) or with an error goodbye ends this
    process at once with exit code 2 and one line naming the process that died, instead of
    waiting in a collective (gloo) for a peer that never comes; process 0 first tells the
    other processes which one died. :func:`finish` says goodbye (the CLI calls it; an
    ``atexit`` hook does it for scripts: clean unless an exception went uncaught). An uncaught
    exception first waits up to ``GRACE_S`` for the watcher: when it came from a collective
    whose peer died, the process ends with that line and exit 2, not a traceback and a hang
    in JAX's shutdown.
    """

    BYE, FAILED, DIED, FAILED_FWD = b"B", b"X", b"D", b"Y"
    GRACE_S = 5.0  # how long an uncaught exception waits for the watcher (``start``)

    def __init__(self) -> None:
        import threading

        self.lock = threading.Lock()
        self.chans: dict = {}
        self.pid, self.n, self.done = 0, 1, False
        self.failed = False

    def start(self, pid: int, n: int, chans: dict) -> None:
        import atexit
        import sys
        import threading
        import time

        self.pid, self.n, self.chans, self.done = pid, n, dict(chans), False
        prev = sys.excepthook

        def hook(*exc):  # an uncaught exception: the goodbye says "failed"
            self.failed = True
            # a collective fails when a peer died, at times before the watcher has read the
            # closed channel: give the watcher GRACE_S to name the dead peer and end this
            # process (exit 2, one line) before the traceback and the interpreter's exit,
            # which says goodbye (stopping the watcher) and runs JAX's shutdown, which then
            # waits for, or aborts on, the dead peer (seen in CI under load: a gloo error's
            # traceback, then a hang or a SIGABRT instead of exit 2)
            for _ in range(int(self.GRACE_S / 0.05)):
                if self.done:
                    break
                time.sleep(0.05)
            prev(*exc)

        sys.excepthook = hook
        atexit.register(lambda: self.finish(not self.failed))
        for q, conn in chans.items():
            threading.Thread(target=self._read, args=(q, conn), daemon=True,
                             name=f"pqrm-watch-{q}").start()

    def _read(self, q: int, conn) -> None:
        import socket
        import struct

        try:
            msg = conn.recv(1)
            if msg in (self.DIED, self.FAILED_FWD):
                (dead,) = struct.unpack("!i", conn.recv(4, socket.MSG_WAITALL))
                return self._end(dead, msg == self.DIED)
        except (OSError, struct.error):
            msg = b""
        if msg == self.BYE:
            return None
        return self._end(q, msg != self.FAILED)

    def _end(self, q: int, died: bool) -> None:
        import struct
        import sys
        import time

        if not died:  # it failed with its own message: let this process end on its own first
            for _ in range(100):
                if self.done:
                    return
                time.sleep(0.1)
        how = "died" if died else "ended with an error"
        with self.lock:
            if self.done:
                return
            self.done = True
            if self.pid == 0:  # tell the others which process it was
                for r, c in self.chans.items():
                    if r != q:
                        try:
                            c.sendall((self.DIED if died else self.FAILED_FWD)
                                      + struct.pack("!i", q))
                        except OSError:
                            pass
        sys.stderr.write(f"pqrm-jax: error: process {q} of {self.n} {how}; process "
                         f"{self.pid} ends too (restart every process to resume)\n")
        sys.stderr.flush()
        from os import _exit  # documented stdlib API: the one way to end a process from a thread

        _exit(2)

    def finish(self, ok: bool = True) -> None:
        with self.lock:
            if self.done or not self.chans:
                return
            self.done = True
            for c in self.chans.values():
                try:
                    c.sendall(self.BYE if ok else self.FAILED)
                except OSError:
                    pass


_WATCH = _Watch()


def finish(ok: bool = True) -> None:
    """Say goodbye to the other processes of a multi-process run (see :class:`_Watch`):
    ``ok=False`` makes them end with exit code 2 naming this process. Idempotent; a no-op
    in a one-process run."""
    _WATCH.finish(ok)


def initialize_from(args, env: Mapping[str, str] | None = None) -> Cluster:
    """:func:`initialize` from the flags of :func:`add_arguments`."""
    return initialize(getattr(args, "coordinator", None), getattr(args, "num_processes", None),
                      getattr(args, "process_id", None),
                      timeout_s=getattr(args, "init_timeout", 60), env=env)


def current() -> Cluster:
    """The :class:`Cluster` of this process as JAX sees it (one process if not started)."""
    import jax

    if not jax.distributed.is_initialized():
        return Cluster(0, 1, None)
    return Cluster(jax.process_index(), jax.process_count(), _STARTED.get("coordinator"))


def share(n: int, cluster: Cluster) -> list[int]:
    """The items of ``range(n)`` this process computes: ``i`` with ``i % N == id``."""
    return list(range(cluster.process_id, n, cluster.num_processes))


def gather(tree: Any, cluster: Cluster) -> Any:
    """Stack a pytree of equal-shaped numpy arrays from every process: leaves ``[N, ...]``.

    With one process the leaves just get the leading axis of size 1 (no collective).
    """
    import jax

    if not cluster.distributed:
        return jax.tree_util.tree_map(lambda x: np.asarray(x)[None], tree)
    from jax.experimental import multihost_utils

    out = multihost_utils.process_allgather(tree, tiled=False)
    return jax.tree_util.tree_map(np.asarray, out)


def broadcast(tree: Any, cluster: Cluster) -> Any:
    """Process 0's value of a pytree of numpy arrays, on every process."""
    if not cluster.distributed:
        return tree
    import jax
    from jax.experimental import multihost_utils

    return jax.tree_util.tree_map(np.asarray, multihost_utils.broadcast_one_to_all(tree))


def agree(cluster: Cluster, config: Any, what: str = "configuration") -> None:
    """Refuse (on every process) to go on when the processes' ``config`` differ.

    ``config`` is anything JSON-serialisable; its SHA-256 is gathered from every process and
    compared with process 0's. Raises :class:`DistributedError` naming the disagreeing ids.
    """
    if not cluster.distributed:
        return
    digest = hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).digest()
    mine = np.frombuffer(digest, np.uint8).astype(np.int32)
    every = gather(mine, cluster)
    bad = [i for i in range(cluster.num_processes) if not np.array_equal(every[i], every[0])]
    if bad:
        raise DistributedError(f"processes {bad} were started with a different {what} than "
                               f"process 0; start every process with the same arguments")


def decide(cluster: Cluster, n: int, fn: Callable[[], Any]) -> np.ndarray:
    """Process 0's ``fn()`` (``n`` integers, e.g. a "unit left to do" mask) on every process.

    Only process 0 calls ``fn`` (it typically opens the study store and reads what is done).
    If ``fn`` raises there, process 0 re-raises and the other processes raise a
    :class:`DistributedError` instead of waiting for results that never come.

    >>> decide(Cluster(0, 1, None), 3, lambda: [1, 0, 1]).tolist()
    [1, 0, 1]
    """
    status = np.zeros(n + 1, np.int32)  # [process 0 succeeded, values...]
    failure = None
    if cluster.is_main:
        try:
            vals = np.asarray(fn(), np.int32).reshape(-1)
            if vals.shape != (n,):
                raise ValueError(f"decide: expected {n} values, got {vals.shape[0]}")
            status[0], status[1:] = 1, vals
        except BaseException as exc:  # tell the other processes before failing
            failure = exc
    status = broadcast(status, cluster)
    if failure is not None:
        raise failure
    if not status[0]:
        raise DistributedError(f"process {cluster.process_id}: process 0 failed while "
                               "preparing the study (see its error)")
    return status[1:]


def _encode(obj: Any, codec: str) -> bytes:
    import io

    if codec == "json":
        return json.dumps(obj, allow_nan=True).encode()
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in obj.items()})
    return buf.getvalue()


def _decode(data: bytes, codec: str) -> Any:
    import io

    if codec == "json":
        return json.loads(data.decode())
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def map_units(fn: Callable[[Any], Any], items: Sequence[Any], cluster: Cluster, *,
              codec: str = "json") -> Iterator[tuple[int, Any]]:
    """``(i, fn(items[i]))`` for every item in order, on every process, computed once.

    Works in rounds of ``N`` items: in round ``j`` process ``p`` computes item ``j·N + p``
    (:func:`share`'s split), then the results are exchanged over the collectives, so a study
    can write each round before the next starts (a killed run resumes after the last written
    round). Results travel encoded: ``codec="json"`` for JSON values (floats round-trip
    exactly) or ``"npz"`` for a ``dict`` of numpy arrays (dtype, shape and bits kept), so the
    results are the bits a single process computes. An error in ``fn`` on any process is
    raised on every process as a :class:`DistributedError` naming that process and item.
    With one process ``fn``'s own results are yielded (nothing is encoded).

    >>> list(map_units(lambda x: x * x, [1, 2, 3], Cluster(0, 1, None)))
    [(0, 1), (1, 4), (2, 9)]
    """
    if codec not in ("json", "npz"):
        raise ValueError(f"codec must be 'json' or 'npz', got {codec!r}")
    if not cluster.distributed:
        for i, item in enumerate(items):
            yield i, fn(item)
        return
    k = cluster.num_processes
    for start in range(0, len(items), k):
        i = start + cluster.process_id
        ok, data = 1, b""
        if i < len(items):
            try:
                data = _encode(fn(items[i]), codec)
            except Exception as exc:  # noqa: BLE001  (reported on every process below)
                ok, data = 0, f"{type(exc).__name__}: {exc}".encode()[:2000]
        head = gather(np.array([ok, len(data)], np.int32), cluster)  # [N, 2]
        width = max(int(head[:, 1].max()), 1)
        buf = np.zeros(width, np.uint8)
        buf[:len(data)] = np.frombuffer(data, np.uint8)
        every = gather(buf, cluster)  # [N, width]
        for q in range(k):
            if start + q < len(items) and not head[q, 0]:
                msg = every[q, :head[q, 1]].tobytes().decode(errors="replace")
                raise DistributedError(f"process {q} failed on item {start + q}: {msg}")
        for q in range(min(k, len(items) - start)):
            yield start + q, _decode(every[q, :head[q, 1]].tobytes(), codec)


def _raise_failures(cluster: Cluster, failure: BaseException | None, what: str) -> None:
    """Every process learns whether any process failed: the failing one raises its own
    error, the others a :class:`DistributedError` naming the first failing process."""
    data = b"" if failure is None else f"{type(failure).__name__}: {failure}".encode()[:2000]
    head = gather(np.array([failure is None, len(data)], np.int32), cluster)  # [N, 2]
    if head[:, 0].all():
        return
    buf = np.zeros(max(int(head[:, 1].max()), 1), np.uint8)
    buf[:len(data)] = np.frombuffer(data, np.uint8)
    every = gather(buf, cluster)  # [N, width]: every process takes part before raising
    if failure is not None:
        raise failure
    q = int(np.flatnonzero(head[:, 0] == 0)[0])
    msg = every[q, :head[q, 1]].tobytes().decode(errors="replace")
    raise DistributedError(f"process {q} failed on {what}: {msg}")


def map_chunks(fn: Callable[[int], Any], n: int, cluster: Cluster, *,
               done: Callable[[int, Any], None] | None = None) -> list[Any]:
    """``[fn(0), ..., fn(n - 1)]`` on every process, each item computed by one process.

    The one work splitter for array work (padgett-mc's chunks of runs, qbsp's chunks of
    environments and its calibration environments): ``fn(i)`` returns a pytree of numpy
    arrays whose shapes are the same for every ``i`` (a padded chunk). Process ``p`` of ``K``
    computes the items ``i ≡ p (mod K)`` (:func:`share`), padded to ``ceil(n / K)`` items by
    repeating its last one (computed, then dropped) so that every process gathers equal
    shapes, and the results are gathered once and put back in item order; each item is
    computed whole on one process, so the results are a one-process run's, bit for bit.
    An error in ``fn`` on any process is raised on every process (the failing one raises it,
    the others a :class:`DistributedError` naming it) instead of leaving them waiting in the
    gather. With one process nothing is padded or exchanged: ``fn``'s own results.

    Args:
        fn: item index → pytree of numpy arrays (equal shapes and dtypes for every item).
        n: the number of items (the same on every process).
        cluster: the processes (:func:`initialize`).
        done: called as ``done(i, result)`` on the computing process after each of its own
            items (not the padding), in its order: a progress bar, or a one-process run's
            write-as-you-go.

    Returns:
        The ``n`` results in item order (gathered leaves are numpy arrays).

    >>> map_chunks(lambda i: np.full(2, i), 3, Cluster(0, 1, None))
    [array([0, 0]), array([1, 1]), array([2, 2])]
    """
    if not cluster.distributed:
        out = []
        for i in range(n):
            out.append(fn(i))
            if done is not None:
                done(i, out[-1])
        return out
    if n == 0:
        return []
    import jax

    k = cluster.num_processes
    mine = share(n, cluster)
    per = -(-n // k)
    todo = mine + [mine[-1] if mine else 0] * (per - len(mine))
    parts, failure = [], None
    try:
        for j, i in enumerate(todo):
            parts.append(jax.tree_util.tree_map(np.asarray, fn(i)))
            if done is not None and j < len(mine):
                done(i, parts[-1])
    except Exception as exc:  # noqa: BLE001  (raised on every process below)
        failure = exc
    _raise_failures(cluster, failure, "its share of the chunks")
    stacked = jax.tree_util.tree_map(lambda *xs: np.stack(xs), *parts)
    every = gather(stacked, cluster)  # leaves [K, per, ...]
    return [jax.tree_util.tree_map(lambda x, i=i: x[i % k, i // k], every) for i in range(n)]
