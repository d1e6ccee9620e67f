"""A throw-away PostgreSQL server for the catalogue tests, started by the tests themselves.

Debian's ``postgresql`` package (``/usr/lib/postgresql/<version>/bin``; ``.ci/run`` installs
it) provides ``initdb`` and ``postgres``. :func:`postgres_server` makes a cluster in its own
scratch directory, starts it on a free loopback port (TCP only, no Unix socket), yields its
URL and stops it (fast shutdown) and removes the directory at the end. PostgreSQL refuses to
run as root, so under root (CI, containers) the server runs as the ``postgres`` system user
the package creates, in a directory made for it. (pytest-postgresql runs ``pg_ctl`` as the
calling user, which fails under root: dbfixtures/pytest-postgresql#341 and #455.)
"""

from __future__ import annotations

import contextlib
import glob
import os
import pwd
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

START_TIMEOUT_S = 60.0


def bindir() -> Path | None:
    """The newest ``/usr/lib/postgresql/<version>/bin`` holding ``initdb`` and ``postgres``."""
    found = [
        Path(d)
        for d in glob.glob("/usr/lib/postgresql/*/bin")
        if (Path(d) / "initdb").is_file() and (Path(d) / "postgres").is_file()
    ]

    def version(d: Path) -> float:
        try:
            return float(d.parent.name)
        except ValueError:
            return 0.0

    return max(found, key=version) if found else None


def why_not() -> str | None:
    """Why no server can be started here (None: it can)."""
    if bindir() is None:
        return (
            "PostgreSQL server binaries not found in /usr/lib/postgresql/*/bin "
            "(apt-get install postgresql; .ci/run installs it)"
        )
    if os.geteuid() == 0:
        try:
            pwd.getpwnam("postgres")
        except KeyError:
            return "running as root and there is no 'postgres' user to run the server as"
    try:
        import psycopg  # noqa: F401
    except ImportError:
        return "the psycopg driver is not installed (pip install 'gyrolab[postgresql]')"
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _scratch() -> Path:
    """A directory the server's user can reach: under $TMPDIR when every directory above
    it lets others through, else under /tmp (the server's user is not the caller's)."""
    base = Path(tempfile.gettempdir())
    if os.geteuid() == 0 and any(not (p.stat().st_mode & 0o001) for p in [base, *base.parents]):
        base = Path("/tmp")
    return Path(tempfile.mkdtemp(prefix="gyrolab-pg-", dir=base))


@contextlib.contextmanager
def postgres_server() -> Iterator[str]:
    """A running server; yields ``postgresql+psycopg://postgres@127.0.0.1:PORT/postgres``."""
    bins = bindir()
    assert bins is not None, why_not()
    scratch = _scratch()
    run_as: dict[str, int] = {}
    if os.geteuid() == 0:
        pw = pwd.getpwnam("postgres")
        run_as = {"user": pw.pw_uid, "group": pw.pw_gid}
        os.chmod(scratch, 0o755)
        os.chown(scratch, pw.pw_uid, pw.pw_gid)
    data, log = scratch / "data", scratch / "server.log"
    proc = None
    try:
        subprocess.run(
            [str(bins / "initdb"), "-D", str(data), "-U", "postgres", "--auth=trust",
             "-E", "UTF8", "--no-sync", "--no-instructions"],
            check=True, capture_output=True, cwd=scratch, **run_as,
        )  # fmt: skip
        port = _free_port()
        with open(log, "wb") as out:
            proc = subprocess.Popen(
                [str(bins / "postgres"), "-D", str(data), "-p", str(port),
                 "-c", "listen_addresses=127.0.0.1", "-c", "unix_socket_directories=",
                 "-c", "fsync=off", "-c", "full_page_writes=off", "-c", "max_connections=50"],
                stdout=out, stderr=subprocess.STDOUT, cwd=scratch, **run_as,
            )  # fmt: skip
        url = f"postgresql+psycopg://postgres@127.0.0.1:{port}/postgres"
        _wait(url, proc, log)
        yield url
    finally:
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGINT)  # fast shutdown
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        shutil.rmtree(scratch, ignore_errors=True)


def _wait(url: str, proc: subprocess.Popen[bytes], log: Path) -> None:
    import psycopg

    dsn = url.replace("postgresql+psycopg://", "postgresql://")
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        if proc.poll() is not None:
            raise RuntimeError(f"postgres exited: {log.read_text(errors='replace')[-2000:]}")
        try:
            psycopg.connect(dsn, connect_timeout=2).close()
            return
        except psycopg.OperationalError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


def create_database(server_url: str, name: str) -> str:
    """A new, empty database on the server; its URL."""
    import psycopg

    dsn = server_url.replace("postgresql+psycopg://", "postgresql://")
    with psycopg.connect(dsn, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    return server_url.rsplit("/", 1)[0] + f"/{name}"
