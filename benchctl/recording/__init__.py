"""The benchctl recording: written as the run goes, readable after any crash.

See ``format`` for the layout; ``RecordingWriter`` writes it, ``load_recording`` reads it.
"""

from benchctl.recording.format import (
    FORMAT_NAME,
    FORMAT_VERSION,
    STREAM_COLUMNS,
    is_recording,
)
from benchctl.recording.reader import (
    Integrity,
    IntegrityError,
    Recording,
    load_recording,
    verify_recording,
)
from benchctl.recording.writer import RecordingWriter

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "STREAM_COLUMNS",
    "Integrity",
    "IntegrityError",
    "Recording",
    "RecordingWriter",
    "is_recording",
    "load_recording",
    "verify_recording",
]
