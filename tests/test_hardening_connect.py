"""Ray and MLflow connections with a deadline, addresses checked up front (issue 29, items 8,
9 and 11).

Every server here is started by the test on 127.0.0.1 (port 0) and stopped by it: a listener
that accepts connections and never answers, and a plain HTTP server.  ``ray.init`` retried such
an address past 300 s and an MLflow export to a silent listener hung 400 s; now each ends in
one line, exit 2, within seconds (the probe's deadline is lowered to 1 s here; its default,
``repro.netprobe.PROBE_TIMEOUT_S``, is 5 s).  A malformed ``--address`` (no port, an empty
port, a 5,000-digit port, ``ray://`` without Ray Client) is refused before any work, a SIGTERM
inside ``ray.init`` leaves the run INTERRUPTED, an export into a folder that is not an MLflow
store is refused, and the MLflow note carries no HTML.
"""

from __future__ import annotations

import http.server
import importlib.util
import os
import signal
import socket
import sys
import threading
import time

import pytest

from repro.errors import ConfigError

needs_mlflow = pytest.mark.skipif(importlib.util.find_spec("mlflow") is None,
                                  reason="needs the mlflow extra (pip install 'repro[mlflow]')")


@pytest.fixture
def fast_probe(monkeypatch):
    from repro import netprobe

    assert netprobe.PROBE_TIMEOUT_S <= 5  # the default keeps every refusal well under 10 s
    monkeypatch.setattr(netprobe, "PROBE_TIMEOUT_S", 1.0)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)


@pytest.fixture
def silent():
    """127.0.0.1:PORT of a listener that accepts (the kernel does) and never answers."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(8)
    try:
        yield f"127.0.0.1:{sock.getsockname()[1]}"
    finally:
        sock.close()


@pytest.fixture
def plain_http(tmp_path):
    """127.0.0.1:PORT of a plain HTTP server (`python -m http.server` of an empty folder)."""
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *a, **kw):
            super().__init__(*a, directory=str(tmp_path / "www"), **kw)

        def log_message(self, *a):
            pass

    (tmp_path / "www").mkdir()
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.1},
                              daemon=True)
    thread.start()
    try:
        yield f"127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cli(capsys, *argv, limit: float = 8.0) -> tuple[int, str, float]:
    """Run the CLI in a thread; fail (not hang) when it takes longer than ``limit``."""
    from cli.main import main

    box: dict = {}
    t0 = time.monotonic()
    th = threading.Thread(target=lambda: box.setdefault("rc", main(list(argv))), daemon=True)
    th.start()
    th.join(limit)
    took = time.monotonic() - t0
    assert not th.is_alive(), f"{' '.join(argv)}: still running after {limit} s"
    return box.get("rc"), capsys.readouterr().err, took


def _one_line(err: str) -> None:
    assert err.count("\n") == 1 and err.startswith("repro: error: ") and "Traceback" not in err


# ---------------------------------------------------------------------- Ray: the address
@pytest.mark.parametrize("address, needle", [
    ("127.0.0.1", "no port"),
    ("127.0.0.1:", "not a Ray address"),
    (":6379", "not a Ray address"),
    ("127.0.0.1:0", "port 0 is not in 1-65535"),
    ("127.0.0.1:70000", "port 70000 is not in 1-65535"),
    ("127.0.0.1:" + "9" * 5000, "characters is no Ray address"),
    ("http://127.0.0.1:8265", "not a Ray address"),
], ids=["no-port", "empty-port", "no-host", "port-0", "port-70000", "port-5000-digits",
        "http"])
def test_malformed_addresses_are_refused_before_ray_is_asked(address, needle):
    from repro.engine.ray_executor import RayBackend

    with pytest.raises(ConfigError, match=needle):
        RayBackend(address)


def test_the_forms_ray_itself_accepts_pass(monkeypatch):
    """``auto`` and ``local`` are Ray's (find a cluster / start a local instance); ``ray://HOST``
    without a port is Ray Client's default port, as Ray reads it."""
    from repro.engine import ray_executor

    assert ray_executor.parse_address("auto") is None
    assert ray_executor.parse_address("local") is None
    monkeypatch.setattr(ray_executor, "_ray_client_missing", lambda: None)
    assert ray_executor.parse_address("ray://head") == ("head", ray_executor.RAY_CLIENT_PORT, True)
    assert ray_executor.parse_address("ray://head:10002") == ("head", 10002, True)
    assert ray_executor.parse_address("head:6379") == ("head", 6379, False)


def test_cli_refuses_a_malformed_address_before_any_work(capsys, tmp_path, monkeypatch):
    from repro.store.runs import run_dirs

    monkeypatch.setenv("REPRO_HOME", str(tmp_path))
    for address in ("127.0.0.1:", "127.0.0.1:" + "9" * 5000):
        rc, err, took = _cli(capsys, "run", "marionette/table1", "--executor", "ray",
                             "--address", address, "--quiet")
        assert rc == 2 and "--address" in err and took < 10, err
        _one_line(err)
    assert run_dirs() == [] and not (tmp_path / "store").exists()


def test_ray_client_address_needs_the_client_extra(monkeypatch, fast_probe):
    from repro.engine import ray_executor

    monkeypatch.setattr(ray_executor, "_ray_client_missing", lambda: "no module named 'grpc'")
    with pytest.raises(ConfigError, match=r"ray://.*pip install 'ray\[client\]'"):
        ray_executor.RayBackend("ray://127.0.0.1:10001")
    pytest.importorskip("ray")
    monkeypatch.setattr(ray_executor, "_ray_client_missing", lambda: None)  # as if installed
    with pytest.raises(ConfigError, match="no Ray cluster answers there"):
        ray_executor.RayBackend(f"ray://127.0.0.1:{_free_port()}")


# ---------------------------------------------------------------------- Ray: silent servers
def test_a_silent_listener_is_refused_within_the_deadline(silent, fast_probe):
    pytest.importorskip("ray")
    from repro.engine.ray_executor import RayBackend

    t0 = time.monotonic()
    with pytest.raises(ConfigError, match=rf"--address {silent}: nothing answered within 1 s"):
        RayBackend(silent)
    assert time.monotonic() - t0 < 3


def test_a_plain_http_server_is_no_ray_cluster(plain_http, fast_probe):
    pytest.importorskip("ray")
    from repro.engine.ray_executor import RayBackend

    with pytest.raises(ConfigError, match="an HTTP server answers there, not a Ray cluster"):
        RayBackend(plain_http)


def test_ray_address_from_the_environment_is_checked_too(silent, fast_probe, monkeypatch,
                                                         capsys, tmp_path):
    pytest.importorskip("ray")
    from repro.store.runs import run_dirs

    monkeypatch.setenv("REPRO_HOME", str(tmp_path))
    monkeypatch.setenv("RAY_ADDRESS", silent)
    rc, err, took = _cli(capsys, "run", "marionette/table1", "--executor", "ray", "--quiet")
    assert rc == 2 and f"RAY_ADDRESS {silent}: nothing answered" in err and took < 10, err
    _one_line(err)
    assert run_dirs() == []


JOB_MODULE = '''
def prepare(ctx):
    raise AssertionError("never runs: the Ray connection is interrupted first")
'''


def test_sigterm_inside_ray_init_records_the_run_interrupted(tmp_path, monkeypatch):
    """Ray's init installs a SIGTERM handler that calls sys.exit: a SIGTERM while it connects
    used to end the run FAILED (SystemExit); it is the executor's interrupt now."""
    from repro.engine import ray_executor
    from repro.engine.executor import execute
    from repro.engine.job_run import CANCELLED
    from repro.engine.job import Job
    from repro.store.objects import Store
    from repro.store.runs import RunRecorder, load_run

    class FakeRay:  # what ray.init does to signals, then a SIGTERM while it "connects"
        up = False

        def is_initialized(self):
            return self.up

        def init(self, **kw):
            self.up = True
            signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(signum))
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
            raise AssertionError("the SIGTERM never arrived")

        def shutdown(self):
            self.up = False

    fake = FakeRay()
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(ray_executor, "import_ray", lambda: fake)
    (tmp_path / "repro_sigterm_jobs.py").write_text(JOB_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    job = Job("prepare", "repro_sigterm_jobs:prepare", {"n": 1}, deterministic=True,
              label="prep", threads=1)
    before = signal.getsignal(signal.SIGTERM)
    with RunRecorder(table="toy/ray-init-sigterm", runs_dir=tmp_path / "runs") as rec:
        try:
            execute([job], store=Store(tmp_path / "store"), recorder=rec, keep_going=True,
                    backend=ray_executor.RayBackend())
        except BaseException as e:  # noqa: BLE001 - which one is the point
            caught = e
    assert type(caught) is KeyboardInterrupt, repr(caught)
    assert signal.getsignal(signal.SIGTERM) == before and not fake.up
    run = load_run(rec.path).run
    assert run["status"] == "INTERRUPTED" and run["note"] == "interrupted (SIGTERM)"
    assert [j["status"] for j in run["jobs"]] == [CANCELLED]


# ---------------------------------------------------------------------- MLflow
@pytest.fixture
def finished_run(monkeypatch):
    from repro.store.runs import RunRecorder

    for var in ("MLFLOW_ALLOW_FILE_STORE", "MLFLOW_DISABLE_TELEMETRY",
                "MLFLOW_HTTP_REQUEST_TIMEOUT", "MLFLOW_HTTP_REQUEST_MAX_RETRIES"):
        monkeypatch.setenv(var, "x")  # restored (removed) after the test, whatever is set
        monkeypatch.delenv(var)
    rec = RunRecorder(table="nowhere/table9", scale="quick")
    rec.start()
    rec.finish()
    return rec.run_id


@needs_mlflow
def test_mlflow_export_to_a_silent_listener_ends_in_seconds(silent, fast_probe, finished_run,
                                                            capsys):
    rc, err, took = _cli(capsys, "runs", "export", finished_run, "--mlflow", f"http://{silent}")
    assert rc == 2 and "did not answer within 1 s" in err and took < 5, err
    _one_line(err)


@needs_mlflow
def test_mlflow_export_to_a_plain_http_server_says_no_tracking_server(plain_http, fast_probe,
                                                                      finished_run, capsys):
    rc, err, _ = _cli(capsys, "runs", "export", finished_run, "--mlflow", f"http://{plain_http}")
    assert rc == 2 and f"no MLflow tracking server at {plain_http} (HTTP 404" in err, err
    _one_line(err)


@needs_mlflow
def test_mlflow_http_requests_get_a_bounded_timeout_and_retries(finished_run):
    from repro.exporters.mlflow_store import HTTP_MAX_RETRIES, HTTP_TIMEOUT_S, _import_mlflow

    _import_mlflow("http://127.0.0.1:5000")
    assert os.environ["MLFLOW_HTTP_REQUEST_TIMEOUT"] == str(HTTP_TIMEOUT_S) == "30"
    assert os.environ["MLFLOW_HTTP_REQUEST_MAX_RETRIES"] == str(HTTP_MAX_RETRIES) == "2"


@needs_mlflow
def test_mlflow_export_refuses_a_folder_that_is_no_store(tmp_path, finished_run, capsys):
    folder = tmp_path / "notes"
    folder.mkdir()
    (folder / "todo.txt").write_text("mine\n")
    (folder / "drafts").mkdir()
    for uri in (str(folder), folder.as_uri()):
        rc, err, _ = _cli(capsys, "runs", "export", finished_run, "--mlflow", uri,
                          "--no-pictures", limit=60)
        assert rc == 2 and "is not empty" in err and "no MLflow file store" in err, err
        _one_line(err)
    assert sorted(p.name for p in folder.iterdir()) == ["drafts", "todo.txt"]  # untouched
    empty = tmp_path / "empty"
    empty.mkdir()
    for _ in range(2):  # an empty folder becomes a store, which is then accepted as one
        rc, err, _ = _cli(capsys, "runs", "export", finished_run, "--mlflow", str(empty),
                          "--no-pictures", limit=60)
        assert rc == 0, err
    assert (empty / ".trash").is_dir()


@needs_mlflow
def test_the_mlflow_note_carries_no_html(tmp_path, finished_run, monkeypatch):
    from repro.exporters import mlflow_runs as mlflow_export

    def artifacts(rec, out, keys, *, pictures=True):
        (out / "table").mkdir(parents=True)
        (out / "table" / "table.md").write_text(
            "| row | <img src=x onerror=alert(1)> |\n|---|---|\n| <script>x</script> | 1 |\n")
        return []

    monkeypatch.setattr(mlflow_export, "write_artifacts", artifacts)
    out = mlflow_export.export_runs([finished_run], str(tmp_path / "store"), pictures=False)
    from mlflow.tracking import MlflowClient

    note = MlflowClient(tracking_uri=out[0]["uri"]).get_run(
        out[0]["mlflow_run"]).data.tags["mlflow.note.content"]
    assert "<" not in note and ">" not in note
    assert "&lt;img src=x onerror=alert(1)&gt;" in note and "&lt;script&gt;" in note
