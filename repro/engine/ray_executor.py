"""Running a job graph on a Ray cluster (issue 15, item 1): ``repro run ... --executor ray``.

:class:`RayBackend` is a back end of :func:`repro.engine.executor.execute`: the executor still
decides what to run (store hits, forced kinds), schedules in dependency order, isolates
failures (``keep_going``: a failing job cancels only its dependents) and records every job in
the run record; only *where* a job computes changes.  Each job becomes one Ray task, submitted
once its inputs are published, asking for ``num_cpus`` = the job's ``threads`` (the scale
profile's count, part of its key) and ``num_gpus`` = 1 when the job computes on a CUDA device
(its ``device``, from the profile or ``--device``), 0 otherwise; the task then sees only the
card Ray gave it, so a ``cuda:N`` job runs there as ``cuda`` (the index is placement, not part of
the key).  The profiles state no memory, so tasks ask for none.

The content-addressed store stays the data path: a task runs the job exactly as a local pool
worker does (:func:`repro.engine.job_run.run_in_worker`: same thread settings, same file lock,
re-check and atomic publish into the store at the driver's path) and returns only the small
manifest of the object it published; Ray's object store never carries a payload.  So a table
computed through Ray is bitwise the table computed locally, and a rerun, local or on Ray, finds
every finished job as a hit.

What a cluster needs (``docs/engine.md``, "Ray executor"): every node sees the store, and the
prepared data under ``REPRO_HOME``, at the driver's path (a shared filesystem mounted at the same
place), and runs the same code.  Each task checks both before it computes: the store through a
probe file the driver writes into it for this run, the code through the source hash of the
job's modules (part of its key); a node that fails either ends the run with a
:class:`~repro.errors.ConfigError` naming the node, the path or the module.  The driver's
``REPRO_*`` environment (``REPRO_HOME`` resolved to its absolute path) is the tasks'
environment.

Ray's own task retries are off: a job whose worker dies (killed, out of memory) is FAILED like a
job that raised, its dependents are cancelled, and the same command again finds the finished
jobs in the store and reruns the rest (a killed training resumes from its scratch checkpoints).

Ray is an optional extra (``pip install 'repro[ray]'``), imported only here and only when a
:class:`RayBackend` is made.
"""

from __future__ import annotations

import logging
import os
import re
import secrets
import signal
import socket
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from repro.engine.executor import Backend, ProgressHook, dispatch_progress
from repro.engine.job import Job
from repro.engine.job_run import CANCELLED, INTERRUPTED, run_in_worker
from repro.errors import ConfigError
from repro.store.object_files import StoredObject
from repro.store.objects import Store

INSTALL_HINT = "pip install 'repro[ray]'"
_STOP_GRACE_S = 10.0  # after a polite cancel (KeyboardInterrupt in the task), force-kill

log = logging.getLogger("repro.engine")


def import_ray():
    """The ``ray`` module, or a :class:`ConfigError` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise ConfigError(f"--executor ray needs Ray, which is not installed: {INSTALL_HINT}") \
            from None
    return ray


#: an ``--address`` (or ``RAY_ADDRESS``) longer than this is refused before it is parsed
MAX_ADDRESS_CHARS = 300
_HOST = r"(?:[A-Za-z0-9](?:[A-Za-z0-9._-]*[A-Za-z0-9])?|\[[0-9A-Fa-f:.]+\])"
_ADDRESS = re.compile(rf"(?P<client>ray://)?(?P<host>{_HOST})(?::(?P<port>[0-9]+))?")
#: Ray Client's port when ``ray://HOST`` names none (Ray's own default)
RAY_CLIENT_PORT = 10001
#: HTTP/2's client connection preface and an empty SETTINGS frame: a gRPC server (a Ray head
#: node's GCS, a Ray Client server) answers with its own SETTINGS frame at once
_H2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n\x00\x00\x00\x04\x00\x00\x00\x00\x00"
_FORMS = ("HOST:PORT of the head node (port 1-65535), ray://HOST[:PORT] (Ray Client), auto "
          "or local")


def parse_address(address: str, where: str = "--address") -> tuple[str, int, bool] | None:
    """``(host, port, client)`` of a Ray address, or None for ``auto`` (Ray finds the cluster
    itself) and ``local`` (Ray starts a new local instance); ``ray://HOST`` without a port is
    Ray Client's default port :data:`RAY_CLIENT_PORT`, as Ray reads it; anything else (no port, an empty host or port, a port outside 1-65535, a scheme
    other than ``ray://``, ``ray://`` without Ray Client's ``grpc`` module) is a
    :class:`ConfigError` naming ``where`` (``--address`` or ``RAY_ADDRESS``), before any work.
    """
    if address in ("auto", "local"):
        return None
    if len(address) > MAX_ADDRESS_CHARS:
        raise ConfigError(f"{where}: {len(address)} characters is no Ray address; give {_FORMS}")
    m = _ADDRESS.fullmatch(address)
    if m is None:
        raise ConfigError(f"{where} {address}: not a Ray address; give {_FORMS}")
    if m["port"] is None and m["client"] is None:
        raise ConfigError(f"{where} {address}: no port; give {_FORMS}")
    text = m["port"] if m["port"] is not None else str(RAY_CLIENT_PORT)
    port = int(text) if len(text) <= 5 else 0
    if not 1 <= port <= 65535:
        raise ConfigError(f"{where} {address}: port {m['port']} is not in 1-65535")
    client = m["client"] is not None
    if client and _ray_client_missing() is not None:
        raise ConfigError(f"{where} {address}: ray:// connects through Ray Client, which needs "
                          f"its extra ({_ray_client_missing()}): pip install 'ray[client]'")
    return m["host"].strip("[]"), port, client


def _ray_client_missing() -> str | None:
    """Why Ray Client cannot run here (Ray's own test: its ``grpc`` module is importable),
    or None."""
    import importlib.util

    return None if importlib.util.find_spec("grpc") is not None else "no module named 'grpc'"


def _check_address(address: str, where: str = "--address") -> None:
    """Refuse, in one line and within :data:`repro.netprobe.PROBE_TIMEOUT_S`, an address Ray
    would retry for minutes (issue 29, item 9): nothing listens there, or what listens does not
    answer an HTTP/2 (gRPC) preface with a SETTINGS frame within it (a plain HTTP server, a
    listener that never answers).  ``auto`` is left to Ray; a cluster whose GCS speaks TLS
    (``RAY_USE_TLS``) is only checked for a listener."""
    from repro import netprobe

    parsed = parse_address(address, where)
    if parsed is None:
        return
    host, port, _ = parsed
    tls = os.environ.get("RAY_USE_TLS", "").lower() in ("1", "true")
    try:
        reply = netprobe.exchange(host, port, b"" if tls else _H2_PREFACE,
                                  enough=lambda b: tls or len(b) >= 9)
    except TimeoutError:
        raise ConfigError(f"{where} {address}: nothing answered within "
                          f"{netprobe.PROBE_TIMEOUT_S:g} s (a Ray cluster answers at once); give "
                          "the head node's GCS address (HOST:6379) or Ray Client's "
                          "(ray://HOST:10001)") from None
    except OSError as e:
        raise ConfigError(f"{where} {address}: no Ray cluster answers there ({e}); start one "
                          "with `ray start --head` or give the head node's address") from None
    if tls:
        return
    if len(reply) < 9 or reply[3] != 0x04 or reply[5:9] != bytes(4):
        what = ("an HTTP server answers there" if reply.lstrip().startswith((b"HTTP/", b"<"))
                else
                "the server there closed the connection unanswered" if not reply
                else "the server there does not speak gRPC")
        raise ConfigError(f"{where} {address}: {what}, not a Ray cluster; give "
                          "the head node's GCS address (HOST:6379) or Ray Client's "
                          "(ray://HOST:10001)")


def _forwarded_env() -> dict[str, str]:
    """The driver's ``REPRO_*`` variables for the tasks, ``REPRO_HOME`` made absolute (data
    sets and run bookkeeping are found through it on every node), and the kernel pinning
    (:func:`repro.kernels.worker_env`): a Ray worker process starts with the raylet's
    environment, so the pin travels with the task and is checked there before it computes."""
    from repro.kernels import worker_env
    from repro.paths import repro_home

    env = {k: v for k, v in os.environ.items() if k.startswith("REPRO_")}
    env.update(worker_env())
    env["REPRO_HOME"] = str(Path(repro_home()).resolve())
    return env


def _ray_job(job: Job, key: str, inputs: tuple[StoredObject, ...], root: str, force: bool,
             threads: int | None, probe: str, source: str, inbox) -> tuple:
    """The Ray task of one job: check that this node sees the driver's store and runs its
    code, then run the job as a local pool worker would (:func:`run_in_worker`)."""
    from repro.engine.source_hash import source_hash

    host = socket.gethostname()
    if not os.path.exists(probe):
        raise ConfigError(
            f"Ray worker on {host} cannot reach the store {root} (the driver's probe file "
            f"{Path(probe).name} is not there): every node must see the store at the same path, "
            "e.g. a shared filesystem mounted there, with REPRO_HOME pointing to it")
    mine = source_hash(job.module, *job.plugins)
    if mine != source:
        raise ConfigError(
            f"Ray worker on {host} runs other code than the driver for job {job.name} "
            f"({job.module}: source hash {mine[:12]} here, {source[:12]} on the driver); "
            "install the same repro on every node (or restart the cluster's workers, which keep "
            "the code they imported)")

    def put(msg) -> None:
        # fire and forget: waiting on the reply (ray.get) would make Ray lend this task's CPUs
        # to another task meanwhile, so more jobs than CPUs would run
        try:
            inbox.put.remote(msg)
        except Exception:  # noqa: BLE001 - progress is best effort; the job's result is not
            pass

    return run_in_worker(job, key, inputs, root, force, threads, put)


class _Inbox:
    """A Ray actor (no CPU) that collects the tasks' "start" / "progress" messages in the order
    each task sent them; the driver takes them in batches."""

    def __init__(self):
        self.msgs: list = []

    def put(self, msg) -> None:
        self.msgs.append(msg)

    def take(self) -> list:
        out, self.msgs = self.msgs, []
        return out


class RayBackend:
    """Runs a graph's jobs as Ray tasks (module docstring); pass it to
    :func:`~repro.engine.executor.execute` as ``backend``.

    ``address``: the cluster (``host:port`` of the head node, ``ray://host:port`` for Ray
    Client, ``auto``); ``None`` connects where ``RAY_ADDRESS`` says or, without it, starts a Ray
    instance on this machine for the run.  A Ray already initialised in this process (a test,
    a notebook) is used as it is and left running.  Ray is imported here, and an ``address``
    (or ``RAY_ADDRESS``) of another form (:func:`parse_address`) or where no gRPC server
    answers within seconds (:func:`_check_address`) is refused here, so a missing install or a
    mistyped address fails before anything is computed (the evaluators train before the graph
    runs); the cluster is joined only when a graph has jobs to run.  A SIGTERM while
    ``ray.init`` connects ends the run INTERRUPTED, as one at any other time.
    """

    def __init__(self, address: str | None = None):
        if address is not None:
            parse_address(address)  # the form first: a typo needs no Ray to be refused
        self.ray = import_ray()
        self.address = address
        if address and address != "auto":
            _check_address(address)
        elif os.environ.get("RAY_ADDRESS", "").strip():  # where Ray itself will connect
            _check_address(os.environ["RAY_ADDRESS"].strip(), "RAY_ADDRESS")

    def __call__(self, store: Store, hook: ProgressHook, by_key: dict[str, Job],
                 threads: int | None) -> _RaySession:
        return _RaySession(self, store, hook, by_key, threads)


class _RaySession(Backend):
    """One graph's connection to the cluster: the probe file, the progress inbox and the
    tasks (a context manager; see :class:`~repro.engine.executor.Backend`)."""

    def __init__(self, cfg: RayBackend, store: Store, hook: ProgressHook,
                 by_key: dict[str, Job], threads: int | None):
        self.cfg, self.ray = cfg, cfg.ray
        self.store, self.hook, self.by_key, self.threads = store, hook, by_key, threads
        self.owned = False
        self.probe: Path | None = None
        self.inbox = None
        self.started: set[str] = set()   # keys whose task announced itself
        self.finished: set[str] = set()  # keys whose outcome the driver has taken
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._drainer: threading.Thread | None = None
        self.keys: dict[Any, str] = {}

    # ------------------------------------------------------------------ set-up
    def __enter__(self) -> _RaySession:
        ray = self.ray
        if not ray.is_initialized():
            # ray.init installs its own SIGTERM handler (sys.exit), which would replace the
            # executor's (SIGTERM -> KeyboardInterrupt: the run recorded INTERRUPTED, the tasks
            # stopped); the handler in place before it is put back
            sigterm = signal.getsignal(signal.SIGTERM)
            try:
                ray.init(address=self.cfg.address, log_to_driver=False,
                         logging_level=logging.WARNING)
            except (ConnectionError, TimeoutError, ValueError) as e:
                raise ConfigError(f"--address {self.cfg.address or 'auto'}: cannot connect to "
                                  f"a Ray cluster ({e})") from None
            except SystemExit as e:
                # Ray's own handler (sys.exit) met a SIGTERM while it connected: hand the
                # signal to the handler that was in place (the executor's: KeyboardInterrupt,
                # the run recorded INTERRUPTED, not FAILED)
                if e.code != signal.SIGTERM:
                    raise
                self._abandon_init()
                if callable(sigterm):
                    sigterm(signal.SIGTERM, None)
                raise KeyboardInterrupt("SIGTERM") from None
            except KeyboardInterrupt:
                self._abandon_init()
                raise
            finally:
                if (threading.current_thread() is threading.main_thread()
                        and sigterm is not None):
                    signal.signal(signal.SIGTERM, sigterm)
            self.owned = True
        try:
            self._open()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def _abandon_init(self) -> None:
        """Undo a ``ray.init`` cut short by a signal (best effort: Ray may be half set up)."""
        try:
            if self.ray.is_initialized():
                self.ray.shutdown()
        except Exception:  # noqa: BLE001 - the interrupt is what the caller must see
            pass

    def _open(self) -> None:
        ray = self.ray
        self.store.tmp_dir.mkdir(parents=True, exist_ok=True)
        # named like the store's other per-process temp files (``<what>-<pid>-<hex>``), so
        # ``repro cache gc`` keeps it while this process lives and removes a stale one
        self.probe = self.store.tmp_dir / f"ray-{os.getpid()}-{secrets.token_hex(6)}"
        self.probe.write_text("written by the driver of a Ray run; removed when it ends\n")
        self.node_cpus = max((float(n.get("Resources", {}).get("CPU", 0)) for n in ray.nodes()
                              if n.get("Alive")), default=0.0)
        self.cluster_gpus = float(ray.cluster_resources().get("GPU", 0))
        self.inbox = ray.remote(_Inbox).options(num_cpus=0).remote()
        self._drainer = threading.Thread(target=self._drain, name="repro-ray-progress",
                                         daemon=True)
        self._drainer.start()
        self.task = ray.remote(_ray_job)
        self.options = {"max_retries": 0, "runtime_env": {"env_vars": _forwarded_env()}}

    def __exit__(self, *exc) -> None:
        self._done.set()
        if self._drainer is not None:
            self._drainer.join(timeout=2.0)
        if self.inbox is not None:
            try:
                self.ray.kill(self.inbox)
            except Exception:  # noqa: BLE001 - the cluster may be gone already
                pass
        if self.probe is not None:
            self.probe.unlink(missing_ok=True)
        if self.owned:
            self.ray.shutdown()

    def _drain(self) -> None:
        while not self._done.wait(0.2):
            try:
                msgs = self.ray.get(self.inbox.take.remote())
            except Exception:  # noqa: BLE001 - inbox gone: no more progress, the jobs go on
                return
            with self._lock:  # a message that arrives after its job's outcome is dropped
                for msg in msgs:
                    if msg[1] in self.finished:
                        continue
                    if msg[0] == "start":
                        self.started.add(msg[1])
                    dispatch_progress(msg, self.hook, self.by_key)

    def _taken(self, handle) -> None:
        """Mark the job of ``handle`` finished before the executor reports it; announce its
        start first if that message has not arrived yet (the hook sees start before end)."""
        key = self.keys.get(handle)
        with self._lock:
            self.finished.add(key)
            if key not in self.started:
                self.started.add(key)
                dispatch_progress(("start", key), self.hook, self.by_key)

    # ------------------------------------------------------------------ the Backend
    def resources(self, job: Job) -> dict[str, Any]:
        """What the task of ``job`` asks Ray for: its threads as CPUs, one GPU when it computes
        on a CUDA device (module docstring).  A request no node can meet is refused here, one
        line, instead of a task Ray would keep pending for ever."""
        from repro.seeding import device_type

        cpus = job.threads or self.threads or 1
        if self.node_cpus and cpus > self.node_cpus:
            raise ConfigError(f"job {job.name} computes with {cpus} threads but the largest node "
                              f"of the Ray cluster has {self.node_cpus:g} CPUs; give the nodes "
                              "more CPUs or use a profile with fewer threads")
        gpus = 0 if device_type(getattr(job, "device", None)) == "cpu" else 1
        if gpus > self.cluster_gpus:
            raise ConfigError(f"job {job.name} computes on {job.device} but the Ray cluster has "
                              "no GPU; add GPU nodes or pass --device cpu")
        return {"num_cpus": cpus, "num_gpus": gpus}

    def submit(self, job, key, inputs, force):
        res = self.resources(job)
        task_job = replace(job, device="cuda") if res["num_gpus"] else job
        ref = self.task.options(name=f"repro:{job.name}", **self.options, **res).remote(
            task_job, key, inputs, str(self.store.root), force, self.threads, str(self.probe),
            job.key_parts()["source"], self.inbox)
        self.keys[ref] = key
        return ref

    def wait(self, handles):
        while True:  # short timeouts keep Ctrl-C and SIGTERM responsive
            ready, _ = self.ray.wait(handles, num_returns=1, timeout=0.5)
            if ready:
                return ready

    def outcome(self, handle):
        from ray.exceptions import RayTaskError

        self._taken(handle)
        try:
            return self.ray.get(handle)
        except RayTaskError as e:  # the job's own exception, with the remote traceback noted
            cause = getattr(e, "cause", None)
            if not isinstance(cause, BaseException):
                raise
            if hasattr(cause, "add_note"):
                cause.add_note(f"raised on a Ray worker:\n{e}")
            raise cause from None

    def stop(self, handles, flag) -> None:
        """Cancel queued tasks and interrupt running ones (KeyboardInterrupt in the task, so the
        store removes its temp output); force-kill what still runs after a grace period."""
        with self._lock:  # the queued first: cancelling a running one frees its CPUs
            order = sorted(handles, key=lambda ref: self.keys.get(ref) in self.started)
        for ref in order:
            self.ray.cancel(ref)
        _, pending = self.ray.wait(handles, num_returns=len(handles), timeout=_STOP_GRACE_S)
        for ref in pending:
            self.ray.cancel(ref, force=True)
        if pending:
            time.sleep(0.5)

    def settled(self, handle):
        ready, _ = self.ray.wait([handle], num_returns=1, timeout=0)
        if ready:
            try:
                status, obj, _ = self.ray.get(handle)
                return status, obj
            except BaseException:  # noqa: BLE001 - cancelled or interrupted
                pass
        return (INTERRUPTED if self.keys.get(handle) in self.started else CANCELLED), None
