"""The MLflow tracking store an export writes into (``--mlflow URI``), opened and checked before
anything is written: split from :mod:`repro.exporters.mlflow_runs`, which says what is written.

Checks, each a one-line :class:`~repro.errors.ConfigError` (exit 2) before MLflow is asked:

- a folder (or ``file:`` URI) that exists, is not empty and is not an MLflow file store (no
  ``.trash`` folder, no ``0/meta.yaml``) is refused: MLflow would turn it into a store, with
  warning tracebacks about every folder it finds there (issue 29, item 11);
- a SQL store needs the full ``mlflow`` package (SQLAlchemy);
- an ``http(s)://`` server must answer a request for ``/api/2.0/mlflow/experiments/search``
  within :data:`repro.netprobe.PROBE_TIMEOUT_S` seconds (5): a listener that never answers
  hung an export 400 s in MLflow's retries (issue 29, item 9); an HTTP 404 there means no
  tracking server.  For the export itself MLflow's request timeout and retry count default to
  :data:`HTTP_TIMEOUT_S` and :data:`HTTP_MAX_RETRIES` (``MLFLOW_HTTP_REQUEST_TIMEOUT`` and
  ``MLFLOW_HTTP_REQUEST_MAX_RETRIES``, set for this process when unset; MLflow's own defaults
  are 120 s and 7 retries with growing back-off).

MLflow 3 refuses file stores unless ``MLFLOW_ALLOW_FILE_STORE`` is true: naming one with
``--mlflow`` is taken as that choice (the variable is set for this process when unset).
``MLFLOW_DISABLE_TELEMETRY`` is set too when unset, so an export sends nothing anywhere but to
the store named.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from repro.errors import ConfigError

INSTALL_HINT = "pip install 'repro[mlflow]'"
RUN_ID_TAG = "repro.run_id"
#: MLflow's per-request timeout (s) and retries for an http(s) store, unless set already
HTTP_TIMEOUT_S, HTTP_MAX_RETRIES = 30, 2


def _import_mlflow(uri: str):
    """Import MLflow for an export to ``uri`` (module docstring: the variables set)."""
    os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
    if uri.split(":", 1)[0].lower() in ("http", "https"):
        os.environ.setdefault("MLFLOW_HTTP_REQUEST_TIMEOUT", str(HTTP_TIMEOUT_S))
        os.environ.setdefault("MLFLOW_HTTP_REQUEST_MAX_RETRIES", str(HTTP_MAX_RETRIES))
    if is_file_store(uri):
        os.environ.setdefault("MLFLOW_ALLOW_FILE_STORE", "true")
    try:
        import mlflow  # noqa: F401
        from mlflow.tracking import MlflowClient
    except ImportError as e:
        raise ConfigError(f"--mlflow needs MLflow, which is not installed ({e}): "
                          f"{INSTALL_HINT}") from None
    return MlflowClient


def is_file_store(uri: str) -> bool:
    """Whether ``uri`` names a file store: ``file:...`` or a plain path."""
    return uri.startswith("file:") or not re.match(r"^[A-Za-z][A-Za-z0-9+.\-]*:", uri)


def tracking_uri(uri: str) -> str:
    """``uri`` as MLflow gets it: a plain path becomes an absolute ``file://`` URI (so a
    relative folder means the same whatever the working directory MLflow later runs in)."""
    if not uri.strip():
        raise ConfigError("--mlflow: give a tracking URI (a folder, file:/path, sqlite:///x.db, "
                          "http://host:port)")
    if is_file_store(uri) and not uri.startswith("file:"):
        p = Path(uri).expanduser().resolve()
        _check_folder(p, uri)
        return p.as_uri()
    if uri.startswith("file:"):
        from urllib.parse import urlparse
        from urllib.request import url2pathname

        _check_folder(Path(url2pathname(urlparse(uri).path)), uri)
    return uri


def _check_folder(p: Path, uri: str) -> None:
    """A file store's folder: new, empty, or an MLflow file store already (module
    docstring); anything else is refused before MLflow writes into it."""
    if p.exists() and not p.is_dir():
        raise ConfigError(f"--mlflow {uri}: not a folder (an MLflow file store is one)")
    if not p.is_dir() or (p / ".trash").is_dir() or (p / "0" / "meta.yaml").is_file():
        return
    try:
        with os.scandir(p) as it:
            first = next(iter(it), None)
    except OSError as e:
        raise ConfigError(f"--mlflow {uri}: cannot read the folder ({e.strerror})") from None
    if first is not None:
        raise ConfigError(f"--mlflow {uri}: the folder is not empty ({first.name!r}, ...) and "
                          "is no MLflow file store (no .trash folder, no 0/meta.yaml); give a "
                          "new or empty folder, or an existing store")


#: URI schemes of MLflow's SQL stores (``sqlite:///x.db``, ``postgresql+psycopg2://...``)
SQL_SCHEMES = ("sqlite", "mysql", "postgresql", "mssql")


def _check_uri(uri: str) -> None:
    """Refuse, in one line and before MLflow is asked, a URI this installation cannot serve: a
    SQL store without SQLAlchemy (mlflow-skinny has none), an http(s) server that does not
    answer within seconds (:func:`_probe_http`; MLflow itself would retry for minutes)."""
    import importlib.util
    from urllib.parse import urlparse

    u = urlparse(uri)
    scheme = u.scheme.split("+")[0].lower()
    if scheme in SQL_SCHEMES and importlib.util.find_spec("sqlalchemy") is None:
        from importlib.metadata import PackageNotFoundError, version

        try:
            pin = f"=={version('mlflow-skinny')}"  # the full package of the same release
        except PackageNotFoundError:
            pin = ""
        raise ConfigError(f"--mlflow {uri}: a {scheme} store needs the full MLflow package "
                          f"(pip install 'mlflow{pin}'); mlflow-skinny, which the [mlflow] "
                          "extra installs, opens a folder, file:/path or http(s)://host:port")
    if scheme in ("http", "https"):
        _probe_http(uri, u, scheme == "https")


_STATUS_LINE = re.compile(rb"HTTP/\d(?:\.\d)? (\d{3})")


def _probe_http(uri: str, u, tls: bool) -> None:
    """One bounded request to the tracking server's experiment search (module docstring):
    refused when nothing accepts the connection, nothing answers in time, the answer is not
    HTTP, or the path is not there (404)."""
    from repro import netprobe

    if re.search(r"[\x00-\x20\x7f-\x9f]", uri):
        raise ConfigError(f"--mlflow {uri}: a URL holds no space or control character")
    try:
        host, port = u.hostname or "", u.port or (443 if tls else 80)
    except ValueError as e:  # a port out of range or not a number
        raise ConfigError(f"--mlflow {uri}: {e}") from None
    path = u.path.rstrip("/") + "/api/2.0/mlflow/experiments/search?max_results=1"
    hostport = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    request = (f"GET {path} HTTP/1.1\r\nHost: {hostport}\r\nUser-Agent: repro\r\n"
               "Accept: application/json\r\nConnection: close\r\n\r\n")
    try:
        reply = netprobe.exchange(host, port, request.encode("ascii", "replace"), tls=tls,
                                  enough=lambda b: b"\n" in b)
    except TimeoutError:
        raise ConfigError(f"--mlflow {uri}: the server at {u.netloc} did not answer within "
                          f"{netprobe.PROBE_TIMEOUT_S:g} s") from None
    except (OSError, UnicodeError) as e:
        raise ConfigError(f"--mlflow {uri}: no tracking server answers at "
                          f"{u.netloc} ({e})") from None
    m = _STATUS_LINE.match(reply)
    if m is None:
        raise ConfigError(f"--mlflow {uri}: the server at {u.netloc} does not answer HTTP")
    if m.group(1) == b"404":
        raise ConfigError(f"--mlflow {uri}: no MLflow tracking server at {u.netloc} (HTTP 404 "
                          f"for {path.split('?')[0]})")


class Store:
    """One MLflow tracking store, opened once per command; MLflow's own errors (an unknown
    scheme, a store it cannot open or write) become a one-line :class:`ConfigError`."""

    def __init__(self, uri: str):
        self.uri = tracking_uri(uri)
        _check_uri(self.uri)
        client_class = _import_mlflow(self.uri)
        from mlflow.exceptions import MlflowException
        from mlflow.tracking.registry import UnsupportedModelRegistryStoreURIException

        self._errors = (MlflowException, OSError, ImportError, ValueError)
        try:
            self.client = client_class(tracking_uri=self.uri)
        except UnsupportedModelRegistryStoreURIException:  # MLflow checks its registry first
            raise ConfigError(f"--mlflow {self.uri}: MLflow has no store for this scheme "
                              "(a folder, file:/path, http(s)://host:port; sqlite:///x.db "
                              "with the full mlflow package)") from None
        except self._errors as e:
            raise ConfigError(f"--mlflow {self.uri}: {_first_line(e)}") from None
        self.call(lambda: self.client.search_experiments(max_results=1))

    def call(self, fn):
        try:
            return fn()
        except self._errors as e:
            raise ConfigError(f"--mlflow {self.uri}: {_first_line(e)}") from None

    def find(self, run_id: str):
        """The active MLflow runs tagged with repro run ``run_id``, in every experiment."""
        from mlflow.entities import ViewType

        def go():
            exps = [e.experiment_id for e in self.client.search_experiments(
                view_type=ViewType.ACTIVE_ONLY)]
            if not exps:
                return []
            return self.client.search_runs(exps, f"tags.`{RUN_ID_TAG}` = '{run_id}'",
                                           run_view_type=ViewType.ACTIVE_ONLY)
        return self.call(go)

    def artifact_location(self) -> str | None:
        """Where a new experiment keeps its artifacts: for a ``sqlite:`` store the folder
        ``mlartifacts`` beside the database file (MLflow's default, ``./mlruns`` of whatever
        folder the export runs in, would scatter them); otherwise MLflow's default."""
        if not self.uri.startswith("sqlite:///") or self.uri.startswith("sqlite:///:memory:"):
            return None
        from urllib.parse import unquote

        db = Path(unquote(self.uri[len("sqlite:///"):].split("?")[0]))
        return (db.expanduser().resolve().parent / "mlartifacts").as_uri()

    def experiment_id(self, name: str) -> str:
        def go():
            exp = self.client.get_experiment_by_name(name)
            if exp is None:
                return self.client.create_experiment(
                    name, artifact_location=self.artifact_location())
            if exp.lifecycle_stage != "active":
                raise ConfigError(f"--mlflow {self.uri}: experiment {name!r} is deleted; "
                                  "restore it or give --experiment another name")
            return exp.experiment_id
        return self.call(go)


def _first_line(e: BaseException) -> str:
    msg = getattr(e, "message", None) or str(e) or type(e).__name__
    return str(msg).strip().splitlines()[0] if str(msg).strip() else type(e).__name__
