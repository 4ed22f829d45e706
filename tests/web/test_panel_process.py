"""The panel is not in the safety loop: the run is the server's child in a session of its own,
writing to files, publishing without waiting — so the server killed in the middle of a run
leaves the run to end as it would have, its verdict and recording whole."""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import psutil
import pytest
from panel import post_json, serve, wait_for


# not realtime: the run is on simulated time (serve's default, config/sim_virtual.yaml), the
# panel killed once its recording exists, and nothing is timed but generous waits
@pytest.mark.slow
def test_the_server_killed_mid_run_leaves_the_run_to_its_verdict(tmp_path: Path) -> None:
    procs: list[subprocess.Popen[bytes]] = []
    with serve(tmp_path, duration_s=60.0, procs=procs) as url:  # simulated time
        post_json(url, "/api/start", {"serial": "20260001", "operator": "demo",
                                      "profile": "0"})
        server = psutil.Process(procs[0].pid)
        runs = wait_for("the run's process", lambda: server.children(), 30)
        assert len(runs) == 1 and "run" in runs[0].cmdline()
        run = runs[0]
        wait_for("the run's recording", lambda: list((tmp_path / "runs").glob("*_20260001")),
                 60)
        procs[0].send_signal(signal.SIGKILL)  # the panel crashes
        procs[0].wait(30)
        assert run.is_running()
        gone, _ = psutil.wait_procs([run], timeout=120)  # no longer ours: no exit code here
        assert gone, "the run did not end by itself"
    (rec,) = (tmp_path / "runs").glob("*_20260001")
    end = json.loads((rec / "end.json").read_text())
    assert end["state"] == "done" and end["reason"] == "PASS"
    assert (rec / "report.html").is_file()


def test_two_starts_at_once_start_one_run(tmp_path: Path) -> None:
    """Two browsers pressing Start together: one run, the other told the station is busy."""
    import asyncio
    import sys

    from repo_paths import ROOT

    from benchctl.errors import InputError
    from benchctl.web.settings import PanelSettings
    from benchctl.web.station import Station

    profile = ROOT / "profiles/paper_vessel_roll_short120.yaml"
    st = Station(PanelSettings(config=ROOT / "config/sim_virtual.yaml", profiles=(profile,)))
    st.command = lambda run, path: [sys.executable, "-c", "pass"]  # type: ignore[method-assign]

    async def go() -> list[object]:
        results = await asyncio.gather(st.start("SN-1", "a", profile),
                                       st.start("SN-2", "b", profile), return_exceptions=True)
        while st.busy:
            await asyncio.sleep(0.05)
        await st.close()
        return list(results)

    results = asyncio.run(go())
    assert sum(isinstance(r, InputError) for r in results) == 1
    assert st.run is not None and st.run.ended and st.run.exit_code == 0
