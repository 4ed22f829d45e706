"""The archive's password is never written or printed: not in a recording (meta.json,
record.json, report, logs, the simulators' log), a plan's files (plan.json, JUnit), the queue,
an export (CSV, .mat), the lock folder, the database's own rows, nor on stdout/stderr — in any
form it is given (``user:pw@``, ``?password=``, a libpq ``key=value`` string) and when the URL
is malformed (a port typo, ``url:`` as a YAML list). The password actually reaches the server:
a real PostgreSQL (``archive_helpers.PgServer``) with a role that logs in by password only.
Where it may come from besides the URL: ``PGPASSWORD``, a pgpass file, a service file
(libpq reads them itself; benchctl must not get in the way)."""

from __future__ import annotations

import contextlib
import io
import os
import socket
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from archive_helpers import PgServer, make_record, make_recording
from hypothesis import given, settings
from hypothesis import strategies as st
from repo_paths import ROOT

from benchctl.archive.service import ArchiveSettings, archive_run, queued
from benchctl.archive.store import Archive, parse_url, shown
from benchctl.cli import main
from benchctl.config import load_config
from benchctl.errors import ArchiveError, ConfigError
from benchctl.redact import MASK, redact, redact_secret, redact_text

SECRET = "Sntl-7f3a9c-pw"  # the sentinel password: found nowhere but in the test's own inputs
ROLE = "guarded"
SERIAL = str(yaml.safe_load((ROOT / "config/sim.yaml").read_text())
             ["sim"]["instrument"]["serial_number"])

SHORT = """
name: secrets_short_roll
description: a short roll for the password tests
reference: ci_short, shortened
kind: roll_spectrum
duration_s: 14
fade_in_s: 2
fade_out_s: 2
seed: 3
band_hz: [0.2, 0.6]
axes:
  roll: {model: exp_cos, sigma_deg: 1.5, period_s: 5.0, damping: 0.2}
"""


@pytest.fixture(scope="module")
def pg() -> Iterator[PgServer]:
    srv = PgServer.start()
    try:
        srv.add_login(ROLE, SECRET)
        yield srv
    finally:
        srv.stop()


def _db(srv: PgServer) -> str:
    name = f"s_{uuid.uuid4().hex[:12]}"
    srv.create_database(name, owner=ROLE)
    return name


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# --- the one function ----------------------------------------------------------------------------

FORMS = [
    (f"postgresql+psycopg://bench:{SECRET}@db.line3:5432/benchctl",
     "postgresql+psycopg://bench:***@db.line3:5432/benchctl"),
    (f"postgresql://bench@db.line3/benchctl?password={SECRET}&sslmode=require",
     "postgresql://bench@db.line3/benchctl?password=***&sslmode=require"),
    (f"postgresql://bench@db.line3/benchctl?sslpassword={SECRET}",
     "postgresql://bench@db.line3/benchctl?sslpassword=***"),
    (f"host=db.line3 user=bench password={SECRET} dbname=benchctl",
     "host=db.line3 user=bench password=*** dbname=benchctl"),
    (f"host=db.line3 password = '{SECRET} x' dbname=benchctl",
     "host=db.line3 password = *** dbname=benchctl"),
    (f"postgresql://bench:{SECRET}@db.line3:54x2/benchctl",  # a port typo
     "postgresql://bench:***@db.line3:54x2/benchctl"),
    (f"postgresql://bench:{SECRET[:4]}@{SECRET[4:]}@db.line3/benchctl",  # an unescaped @
     "postgresql://bench:***@db.line3/benchctl"),
    (f"postgresql://bench@db.line3/benchctl?pass%77ord={SECRET}",  # an escaped key
     "postgresql://bench@db.line3/benchctl?password=***"),
]


@pytest.mark.parametrize(("url", "expected"), FORMS)
def test_redact_hides_the_password_in_every_form(url: str, expected: str) -> None:
    assert redact_text(url) == expected
    assert SECRET not in shown(url)
    assert redact({"archive": {"url": [url], "password": SECRET}}) == {
        "archive": {"url": [expected], "password": MASK}}


def test_redact_leaves_what_holds_no_password() -> None:
    for text in ("sqlite:////var/lib/benchctl/archive.sqlite",
                 "postgresql+psycopg://bench@db.line3:5432/benchctl?sslmode=require",
                 "postgresql://db:5432/x failed for user bench@line3",
                 "operator anna: PASS", ""):
        assert redact_text(text) == text
    assert redact_secret(f"server said {SECRET}!", SECRET) == "server said ***!"


_URL_SAFE = st.text(alphabet=st.characters(codec="ascii", categories=["L", "N"],
                                           include_characters="-._~!$'()*+,;=:@/%"),
                    min_size=1, max_size=40)
_QUERY_SAFE = st.text(alphabet=st.characters(codec="ascii", categories=["L", "N"],
                                             include_characters="-._~!$'()*+,;=:@/%?"),
                      min_size=1, max_size=40)
_QUOTED = st.text(alphabet=st.characters(codec="utf-8", categories=["L", "N", "P", "S", "Zs"],
                                         exclude_characters="'\\"), min_size=1, max_size=40)


@settings(max_examples=200, deadline=None)
@given(pw=_URL_SAFE, user=st.from_regex(r"[a-z][a-z0-9_]{0,10}", fullmatch=True))
def test_redact_property_userinfo(pw: str, user: str) -> None:
    url = f"postgresql+psycopg://{user}:{pw}@db.line3:5432/benchctl"
    assert redact_text(url) == f"postgresql+psycopg://{user}:***@db.line3:5432/benchctl"


@settings(max_examples=200, deadline=None)
@given(pw=_QUERY_SAFE, key=st.sampled_from(["password", "PASSWORD", "sslpassword"]))
def test_redact_property_query_and_keywords(pw: str, key: str) -> None:
    url = f"postgresql://bench@db.line3/benchctl?{key}={pw}&sslmode=require"
    out = redact_text(url)
    assert f"{key}=***&sslmode=require" in out and "db.line3/benchctl" in out
    assert redact_text(f"host=h {key}={pw} dbname=d") == f"host=h {key}=*** dbname=d"


@settings(max_examples=200, deadline=None)
@given(pw=_QUOTED)
def test_redact_property_quoted_keyword(pw: str) -> None:
    assert redact_text(f"host=h password='{pw}' dbname=d") == "host=h password=*** dbname=d"


# --- malformed URLs and config forms: the message hides the password -----------------------------

def _config_text(tmp: Path, archive: dict[str, Any] | str, base: str = "config/sim.yaml") -> str:
    """``base`` (the simulated bench) with ``archive`` and the test's folders."""
    data = yaml.safe_load((ROOT / base).read_text())
    data["stand"]["register_map"] = str(ROOT / "drivers/stand_generic.yaml")
    data["instrument"]["eds"] = str(ROOT / "drivers/cia410_inclinometer.eds")
    data["run"]["output_dir"] = str(tmp / "runs")
    data["run"]["lock_dir"] = str(tmp / "locks")
    text = yaml.safe_dump({k: v for k, v in data.items() if k != "archive"}, sort_keys=False)
    if isinstance(archive, str):  # written as it is (a YAML form safe_dump would not make)
        return text + archive
    return text + yaml.safe_dump({"archive": archive}, sort_keys=False)


VIRTUAL = "config/sim_virtual.yaml"  # the simulated bench on simulated time

MALFORMED = {
    "port typo": f"archive:\n  url: postgresql+psycopg://bench:{SECRET}@127.0.0.1:54x2/db\n",
    "port out of range": f"archive:\n  url: postgresql://bench:{SECRET}@127.0.0.1:99999/db\n",
    "a YAML list": f"archive:\n  url: [postgresql+psycopg://bench:{SECRET}@127.0.0.1/db]\n",
    "a YAML list, query form": f"archive:\n  url:\n    - postgresql://b@h/db?password={SECRET}\n",
    "libpq key=value": f"archive:\n  url: host=127.0.0.1 user=bench password={SECRET}\n",
    "key=value, quoted": f"archive:\n  url: \"host=h password='{SECRET} x'\"\n",
    "a mapping": f"archive:\n  url: {{host: h, password: {SECRET}}}\n",
    "a driver typo": f"archive:\n  url: postgresql+psycopg2://bench:{SECRET}@h/db\n",
}


@pytest.mark.parametrize("form", list(MALFORMED))
def test_a_malformed_archive_url_is_refused_without_its_password(
        form: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "bench.yaml"
    cfg.write_text(_config_text(tmp_path, MALFORMED[form]))
    with pytest.raises(ConfigError) as e:
        load_config(cfg)
    assert SECRET not in str(e.value) and "archive.url" in str(e.value)
    profile = tmp_path / "short.yaml"
    profile.write_text(SHORT)
    for argv in (["run", "--config", str(cfg), "--profile", str(profile), "--serial", SERIAL,
                  "--operator", "anna"],
                 ["archive", "sync", "--config", str(cfg)],
                 ["archive", "status", "--config", str(cfg)],
                 ["history", "--config", str(cfg)]):
        assert main(argv) == 2, argv
        out, err = capsys.readouterr()
        assert SECRET not in out + err, (argv, out, err)
        assert "archive.url" in err, (argv, err)
    assert not (tmp_path / "runs").exists()  # refused before anything: nothing moved


@pytest.mark.parametrize("url", [
    f"postgresql+psycopg://bench:{SECRET}@127.0.0.1:54x2/db",
    f"host=127.0.0.1 user=bench password={SECRET}",
    f"mysql://bench:{SECRET}@127.0.0.1/db",
    f"postgresql+asyncpg://bench@h/db?password={SECRET}",
    f"sqlite+pysqlcipher://:{SECRET}@/x.db",
])
def test_a_malformed_url_option_is_refused_without_its_password(
        url: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ArchiveError) as e:
        parse_url(url)
    assert SECRET not in str(e.value)
    for cmd in (["archive", "sync"], ["archive", "status"], ["history"]):
        assert main([*cmd, "--url", url, "--out", str(tmp_path)]) == 2
        out, err = capsys.readouterr()
        assert SECRET not in out + err and "--url" in err, (cmd, err)


def test_a_queued_record_and_its_warning_hide_the_query_form(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    rec = make_recording(tmp_path / "runs", "R", record=make_record("R"))
    dead = f"postgresql+psycopg://bench@127.0.0.1:{_closed_port()}/x?password={SECRET}"
    with caplog.at_level("DEBUG"):
        assert archive_run(ArchiveSettings(dead, tmp_path / "q"), rec) == "queued"
    assert "queued" in caplog.text and "password=***" in caplog.text
    assert SECRET not in caplog.text
    _assert_nowhere(tmp_path, exclude=())


# --- where the password may come from ------------------------------------------------------------

def test_the_password_from_libpq_sources_not_the_url(
        pg: PgServer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A URL without a password: libpq finds it in PGPASSWORD, in a pgpass file
    (PGPASSFILE) or through a service file (PGSERVICEFILE + ``?service=``); a wrong one
    is said as ``denied``, not ``unreachable``."""
    db = _db(pg)
    bare = f"postgresql+psycopg://{ROLE}@127.0.0.1:{pg.port}/{db}"
    for var in ("PGPASSWORD", "PGPASSFILE", "PGSERVICEFILE", "PGSERVICE"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("PGPASSFILE", str(tmp_path / "none"))  # not the user's own ~/.pgpass
    with pytest.raises(ArchiveError) as e:
        Archive(bare)
    assert e.value.kind == "denied" and "denied" in str(e.value)
    monkeypatch.setenv("PGPASSWORD", SECRET)
    with Archive(bare) as a:
        a.store(make_record("from-env"))
    monkeypatch.delenv("PGPASSWORD")
    passfile = tmp_path / "pgpass"
    passfile.write_text(f"127.0.0.1:{pg.port}:{db}:{ROLE}:{SECRET}\n")
    passfile.chmod(0o600)
    monkeypatch.setenv("PGPASSFILE", str(passfile))
    with Archive(bare) as a:
        a.store(make_record("from-pgpass"))
    monkeypatch.setenv("PGPASSFILE", str(tmp_path / "none"))
    services = tmp_path / "pg_service.conf"
    services.write_text(f"[archive]\nhost=127.0.0.1\nport={pg.port}\ndbname={db}\n"
                        f"user={ROLE}\npassword={SECRET}\n")
    monkeypatch.setenv("PGSERVICEFILE", str(services))
    with Archive("postgresql+psycopg://?service=archive") as a:
        a.store(make_record("from-service"))
        assert a.run_ids() == {"from-env", "from-pgpass", "from-service"}
    assert main(["history", "--url", "postgresql+psycopg://?service=archive", "--json"]) == 0
    assert "from-service" in capsys.readouterr().out


# --- a whole run, a plan, sync, status, history, show and export ---------------------------------

def _assert_nowhere(root: Path, exclude: tuple[Path, ...]) -> list[Path]:
    """Every file under ``root`` (but ``exclude``, the test's own inputs) read byte by byte:
    the password in none of them, in any spelling it could be written in."""
    needles = [SECRET.encode(), SECRET.encode("utf-16-le"), SECRET.encode("utf-32-le")]
    seen = []
    for p in sorted(root.rglob("*")):
        if not p.is_file() or p.is_symlink() or p in exclude:
            continue
        data = p.read_bytes()
        for n in needles:
            assert n not in data, f"{p}: holds the password"
        seen.append(p)
    return seen


@pytest.mark.slow
def test_a_whole_run_plan_sync_and_export_write_and_print_no_password(
        pg: PgServer, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture) -> None:
    """``benchctl run`` (its own simulators) with the password in the URL's user part,
    ``benchctl plan`` with it as ``?password=``, both storing into a PostgreSQL role that
    logs in by that password only; a run queued against a dead server and ``archive sync``;
    ``archive status``, ``history``, ``show``, ``recording show`` and ``export`` (CSV and
    .mat). Then every byte under the test's folder — recordings, plan folder, JUnit, queue,
    lock folder, exports — and everything printed or logged, and the database's rows. The run
    and the plan on simulated time (config/sim_virtual.yaml's bench, in this process); the
    PostgreSQL server is real."""
    for var in ("PGPASSWORD", "PGPASSFILE", "PGSERVICEFILE", "PGSERVICE"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("PGPASSFILE", str(tmp_path / "none"))
    db = _db(pg)
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    profile = inputs / "short.yaml"
    profile.write_text(SHORT)
    run_cfg = inputs / "run.yaml"
    run_cfg.write_text(_config_text(tmp_path, {
        "url": f"postgresql+psycopg://{ROLE}:{SECRET}@127.0.0.1:{pg.port}/{db}"}, VIRTUAL))
    plan_cfg = inputs / "plan-bench.yaml"
    plan_cfg.write_text(_config_text(tmp_path, {
        "url": f"postgresql://{ROLE}@127.0.0.1:{pg.port}/{db}?password={SECRET}"}, VIRTUAL))
    dead_cfg = inputs / "dead.yaml"
    dead_cfg.write_text(_config_text(tmp_path, {
        "url": f"postgresql+psycopg://{ROLE}:{SECRET}@127.0.0.1:{_closed_port()}/{db}"}, VIRTUAL))
    plan = inputs / "plan.yaml"
    plan.write_text(yaml.safe_dump({
        "name": "secrets", "config": str(plan_cfg), "operator": "anna",
        "steps": [{"name": "roll", "profile": str(profile), "limits": {"sigma_deg": 3.0}}]}))
    exports = tmp_path / "exports"
    printed = io.StringIO()

    def cli(*argv: str) -> int:
        with contextlib.redirect_stdout(printed):
            code = main(list(argv))
        out, err = capsys.readouterr()
        printed.write(out + err)
        print(argv[:2], code, err[-2000:])  # shown when the test fails
        return code

    with caplog.at_level("DEBUG"):
        assert cli("run", "--config", str(run_cfg), "--profile", str(profile), "--serial",
                   SERIAL, "--operator", "anna") == 0
        runs = tmp_path / "runs"
        (rec,) = [d for d in runs.iterdir() if (d / "meta.json").is_file()]
        assert cli("plan", str(plan), "--serial", SERIAL, "--junit",
                   str(exports / "plan.xml"), "--json") == 0
        # a run whose archive is down: queued; the queue sent by archive sync
        assert archive_run(ArchiveSettings(
            load_config(dead_cfg).archive.url or "", runs / "archive-queue"),
            rec) == "queued"
        assert cli("archive", "status", "--config", str(dead_cfg)) == 0
        assert cli("archive", "sync", "--config", str(dead_cfg)) == 2  # unreachable, said
        assert queued(runs / "archive-queue")
        assert cli("archive", "sync", "--config", str(run_cfg), "--json") == 0
        assert queued(runs / "archive-queue") == []
        assert cli("archive", "status", "--config", str(plan_cfg), "--json") == 0
        assert cli("history", "--config", str(plan_cfg), "--json") == 0
        assert cli("show", rec.name, "--config", str(run_cfg), "--json") == 0
        assert cli("recording", "show", str(rec), "--json") == 0
        assert cli("recording", "export", str(rec), "--csv", str(exports / "csv")) == 0
        assert cli("recording", "export", str(rec), "--mat", str(exports / "r.mat")) == 0
        assert cli("archive", "rebuild", str(runs), "--config", str(run_cfg)) == 0
    files = _assert_nowhere(tmp_path, exclude=(run_cfg, plan_cfg, dead_cfg))
    text = printed.getvalue()
    assert SECRET not in text, "printed"
    assert SECRET not in caplog.text, "logged"
    assert "unreachable" in text and "***" in text  # the dead archive named, masked
    names = {p.name for p in files}
    assert {"meta.json", "record.json", "benchctl.log", "plan.json", "plan.xml",
            "r.mat"} <= names, names
    with Archive(f"postgresql+psycopg://{ROLE}@127.0.0.1:{pg.port}/{db}?password={SECRET}"
                 ) as a:
        ids = a.run_ids()
        assert rec.name in ids and len(ids) == 2  # the run and the plan's step
        with a.engine.connect() as conn:
            from sqlalchemy import text as sql

            rows = conn.execute(sql("SELECT r::text FROM runs r")).scalars().all()
            rows += conn.execute(sql("SELECT m::text FROM measurements m")).scalars().all()
    assert rows and not any(SECRET in r for r in rows)
    meta = (rec / "meta.json").read_text()
    assert f"{ROLE}:***@127.0.0.1" in meta  # the URL kept for the reader, its password hidden
    assert os.stat(rec / "meta.json").st_size > 0
