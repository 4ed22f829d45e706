"""The digest of what a run recorded: one SHA-256 per data file, comparable between two runs.

A run on simulated time records the same bytes for the same inputs — bench config, profile,
seed, the simulated clock's epoch, the code and the libraries. Two fields of ``events.jsonl``
cannot be the same and are left out of its digest: the recording's own path (``recording``)
and the software version (``software_version``); so is the folder a path inside the data
starts with (``root``: e.g. a checkout whose driver files an instrument's identity names).
Everything else — every sample of ``stand.csv``, ``instrument.csv`` and ``setpoints.csv``,
every other field of every event — is in the digest as written.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from benchctl.jsonout import dumps

#: the data files a digest covers: the streams and the events (meta.json holds the start's host
#: facts and end.json the wall-clock figures, which are not the run's data)
DATA_FILES = ("stand.csv", "instrument.csv", "setpoints.csv", "events.jsonl")
#: events.jsonl's fields that cannot be the same in two recordings of the same run
UNFIXABLE = ("recording", "software_version")


def file_digest(path: str | Path, root: str | Path | None = None) -> str | None:
    """The SHA-256 (hex) of one data file as :mod:`benchctl.recording.digest` defines it; None
    when the file is absent."""
    path = Path(path)
    if not path.is_file():
        return None
    data = path.read_bytes()
    if path.name == "events.jsonl":
        text = data.decode()
        if root is not None:
            text = text.replace(str(root), "<root>")
        lines = []
        for line in text.splitlines():
            ev = json.loads(line)
            for key in UNFIXABLE:
                ev.pop(key, None)
            lines.append(dumps(ev, sort_keys=True))
        data = "\n".join(lines).encode()
    return hashlib.sha256(data).hexdigest()


def data_digest(folder: str | Path, root: str | Path | None = None) -> dict[str, str | None]:
    """Each data file's digest (:data:`DATA_FILES`; None: not in the recording)."""
    return {name: file_digest(Path(folder) / name, root) for name in DATA_FILES}


def combined_digest(folder: str | Path, root: str | Path | None = None) -> str:
    """One SHA-256 over every data file's digest, in :data:`DATA_FILES`'s order: equal for two
    recordings exactly when each of their data files is."""
    parts = data_digest(folder, root)
    return hashlib.sha256(
        "\n".join(f"{k} {v}" for k, v in parts.items()).encode()).hexdigest()
