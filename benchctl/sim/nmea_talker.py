"""NMEA 0183 attitude sentences as a talker sends them (formatting only; the pty is ``PtyPort``).

Conventions as in ``benchctl.devices.nmea0183``: roll positive starboard down (port up), pitch
positive bow up; two decimals (0.01°) as the common devices send. Each function returns the
whole line with checksum and CR LF.
"""

from __future__ import annotations

import random

from benchctl.devices.nmea0183 import checksum

#: resolution of the angles in the sentences formatted here (deg)
RESOLUTION_DEG = 0.01


def _line(body: str) -> bytes:
    return f"${body}*{checksum(body):02X}\r\n".encode("ascii")


def hhmmss(t_utc_s: float) -> str:
    """UTC time of day ``hhmmss.sss`` for ``t_utc_s`` seconds since the epoch (or midnight)."""
    ms = round((t_utc_s % 86400.0) * 1000.0) % 86_400_000
    h, rem = divmod(ms, 3_600_000)
    m, rem = divmod(rem, 60_000)
    return f"{h:02d}{m:02d}{rem / 1000.0:06.3f}"


def pashr(t_utc_s: float, roll_deg: float, pitch_deg: float, heading_deg: float = 0.0) -> bytes:
    """``$PASHR,hhmmss.sss,heading,T,roll,pitch,heave,roll_acc,pitch_acc,heading_acc,1,1``."""
    return _line(f"PASHR,{hhmmss(t_utc_s)},{heading_deg:06.2f},T,{roll_deg:+07.2f},"
                 f"{pitch_deg:+07.2f},+00.00,0.010,0.010,0.100,1,1")


def phtro(roll_deg: float, pitch_deg: float) -> bytes:
    """``$PHTRO,pitch,M|P,roll,B|T`` (M bow up, P bow down; T port up, B port down)."""
    return _line(f"PHTRO,{abs(pitch_deg):.2f},{'M' if pitch_deg >= 0 else 'P'},"
                 f"{abs(roll_deg):.2f},{'T' if roll_deg >= 0 else 'B'}")


def xdr(roll_deg: float, pitch_deg: float, talker: str = "II") -> bytes:
    """``$IIXDR,A,pitch,D,PTCH,A,roll,D,ROLL``."""
    return _line(f"{talker}XDR,A,{pitch_deg:.2f},D,PTCH,A,{roll_deg:.2f},D,ROLL")


def sentence(kind: str, t_utc_s: float, roll_deg: float, pitch_deg: float) -> bytes:
    """The line for ``kind`` (``PASHR``, ``PHTRO`` or ``XDR``)."""
    if kind == "PASHR":
        return pashr(t_utc_s, roll_deg, pitch_deg)
    if kind == "PHTRO":
        return phtro(roll_deg, pitch_deg)
    if kind == "XDR":
        return xdr(roll_deg, pitch_deg)
    raise ValueError(f"unknown NMEA 0183 sentence {kind!r}: expected PASHR, PHTRO or XDR")


def garble(line: bytes, how: str, rng: random.Random) -> bytes:
    """A damaged copy of ``line``: ``checksum`` (one character changed), ``truncated`` (cut
    before the checksum, line end kept) or ``range`` (roll field beyond ±180°, checksum valid)."""
    if how == "checksum":
        body_end = line.index(b"*")
        i = rng.randrange(1, body_end)
        ch = line[i:i + 1]
        new = b"7" if ch != b"7" else b"8"
        return line[:i] + new + line[i + 1:]
    if how == "truncated":
        return line[: rng.randrange(2, line.index(b"*"))] + b"\r\n"
    if how == "range":
        text = line.decode("ascii")
        body = text[1:text.index("*")]
        f = body.split(",")
        idx = {"PASHR": 4, "PHTRO": 3}.get(f[0], 6)  # XDR: the ROLL value
        f[idx] = "999.99"
        return _line(",".join(f))
    raise ValueError(f"unknown NMEA garbling {how!r}: expected checksum, truncated or range")
