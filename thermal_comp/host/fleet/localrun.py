"""A local mosquitto and PostgreSQL in a temporary directory, for the tests, the bench and a
try-out on one machine (Debian's packages: scripts/install-system-deps.sh).

``Mosquitto(workdir)``: ``mosquitto -c <conf> `` on a free port, with persistence (so a restart
keeps the sessions and their queued messages), optional users (``mosquitto_passwd``), an ACL
and TLS. ``Postgres()``: ``initdb`` + ``pg_ctl`` in a fresh directory on a free port; as root
it runs as Debian's ``postgres`` user (PostgreSQL refuses to run as root), the way
cnc/session.py runs LinuxCNC unprivileged.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from thermal_comp.host.fleet.topics import FleetError

PG_USER = "postgres"  # Debian's postgresql package creates it


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_port(port: int, timeout_s: float, proc: subprocess.Popen | None = None,
               what: str = "server", log: Path | None = None) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            tail = log.read_text(errors="replace")[-800:] if log and log.exists() else ""
            raise FleetError(f"{what} exited with {proc.returncode}: {tail}")
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise FleetError(f"{what} did not listen on port {port} within {timeout_s:g} s")


def have_mosquitto() -> bool:
    return shutil.which("mosquitto") is not None or os.path.exists("/usr/sbin/mosquitto")


def _mosquitto_bin() -> str:
    return shutil.which("mosquitto") or "/usr/sbin/mosquitto"


class Mosquitto:
    """A mosquitto broker on 127.0.0.1:<free port>; ``users`` {name: password} turns
    anonymous access off; ``acl`` is the ACL file's text; ``tls`` (cert, key) paths."""

    def __init__(self, workdir: str | Path, users: dict[str, str] | None = None,
                 acl: str | None = None, tls: tuple[str, str] | None = None,
                 port: int | None = None) -> None:
        self.dir = Path(workdir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.port = port or free_port()
        self.proc: subprocess.Popen | None = None
        self.log = self.dir / "mosquitto.log"
        me = pwd.getpwuid(os.geteuid()).pw_name
        lines = [f"listener {self.port} 127.0.0.1", "persistence true",
                 f"persistence_location {self.dir}/", "autosave_interval 1",
                 f"user {me}", "max_queued_messages 0", "max_inflight_messages 100",
                 "log_dest stderr", "log_type error", "log_type warning", "log_type notice"]
        if users:
            pw = self.dir / "passwd"
            pw.write_text("")
            for name, password in users.items():
                subprocess.run(["mosquitto_passwd", "-b", str(pw), name, password],
                               check=True, capture_output=True)
            lines += ["allow_anonymous false", f"password_file {pw}"]
        else:
            lines.append("allow_anonymous true")
        if acl is not None:
            (self.dir / "acl").write_text(acl)
            lines.append(f"acl_file {self.dir / 'acl'}")
        if tls is not None:
            lines += [f"certfile {tls[0]}", f"keyfile {tls[1]}"]
        self.conf = self.dir / "mosquitto.conf"
        self.conf.write_text("\n".join(lines) + "\n")

    @property
    def url(self) -> str:
        return f"mqtt://127.0.0.1:{self.port}"

    def start(self) -> Mosquitto:
        fh = self.log.open("a")
        self.proc = subprocess.Popen([_mosquitto_bin(), "-c", str(self.conf)], stdout=fh,
                                     stderr=subprocess.STDOUT)
        fh.close()
        _wait_port(self.port, 10, self.proc, "mosquitto", self.log)
        return self

    def stop(self) -> None:
        """SIGTERM: mosquitto saves its persistence file (sessions, queued messages)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None

    def restart(self, down_s: float = 0.0) -> None:
        self.stop()
        time.sleep(down_s)
        self.start()

    def __enter__(self) -> Mosquitto:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def pg_bin(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    hits = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"),
                  key=lambda p: int(p.split("/")[4]) if p.split("/")[4].isdigit() else 0)
    return hits[-1] if hits else None


def have_postgres() -> bool:
    if pg_bin("initdb") is None or pg_bin("pg_ctl") is None:
        return False
    if os.geteuid() == 0:
        try:
            pwd.getpwnam(PG_USER)
        except KeyError:
            return False
    return True


class Postgres:
    """A throw-away PostgreSQL cluster (trust authentication on 127.0.0.1 only)."""

    def __init__(self, port: int | None = None) -> None:
        self.port = port or free_port()
        self.dir = Path(tempfile.mkdtemp(prefix="tc-pg-"))
        self.user = PG_USER if os.geteuid() == 0 else None
        if self.user:
            pw = pwd.getpwnam(self.user)
            os.chown(self.dir, pw.pw_uid, pw.pw_gid)
        self.data = self.dir / "data"

    @property
    def url(self) -> str:
        return f"postgresql://fleet@127.0.0.1:{self.port}/postgres"

    def _run(self, *cmd: str, timeout: float = 60) -> None:
        full = list(cmd)
        if self.user:
            full = ["runuser", "-u", self.user, "--", *full]
        proc = subprocess.run(full, capture_output=True, text=True, timeout=timeout,
                              cwd=self.dir)
        if proc.returncode != 0:
            raise FleetError(f"{' '.join(cmd[:2])} failed: {proc.stderr.strip()[-600:]}")

    def start(self) -> Postgres:
        initdb, pg_ctl = pg_bin("initdb"), pg_bin("pg_ctl")
        if initdb is None or pg_ctl is None:
            raise FleetError("PostgreSQL's initdb/pg_ctl not found: install the Debian package "
                             "postgresql (scripts/install-system-deps.sh does)")
        self._run(initdb, "-D", str(self.data), "-U", "fleet", "-A", "trust", "-E", "UTF8",
                  "--no-sync")
        opts = (f"-p {self.port} -k {self.dir} -c listen_addresses=127.0.0.1 -c fsync=on "
                "-c max_connections=50")
        self._run(pg_ctl, "-D", str(self.data), "-l", str(self.dir / "pg.log"), "-o", opts,
                  "-w", "-t", "60", "start")
        _wait_port(self.port, 30, what="postgres")
        return self

    def stop(self) -> None:
        pg_ctl = pg_bin("pg_ctl")
        if pg_ctl and self.data.exists():
            try:
                self._run(pg_ctl, "-D", str(self.data), "-m", "fast", "-w", "stop")
            except (FleetError, subprocess.TimeoutExpired):
                pass
        shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> Postgres:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
