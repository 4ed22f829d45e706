"""The panel's own words for what a run tells it: every text the operator reads composed here
from the message catalogs (``benchctl.web.i18n``), in the station's language.

A run speaks English: its abort reason, its description of the stand after an abort, its live
messages, a refusal's error line. The panel does not show those as its sentences. It composes
its own from the structured fields the run gives beside them — the abort's ``kind``,
``source`` and ``error`` (the exception's class), the stand's state after it (``abort.stand``:
angles, rates, servo, fault code, E-stop, at rest, at zero, the commands that bring it back) —
and keeps the run's English text as a **detail**: a secondary line of technical diagnostics,
shown verbatim (always as text, never as markup). A live message the panel knows (a fixed text,
or one of a known form) gets its translation, its variable part as the detail; any other is
shown as a detail alone.

Texts are marked with ``_`` (a string literal alone: ``pybabel extract`` reads them, see
``babel.cfg``) and translated and filled in where they are used (``Words``).
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Mapping
from typing import Any

from benchctl.web.i18n import _, translations

# ---------------------------------------------------------------- the run's words it knows
#: axis names of the stand, as the operator reads them
AXES = {"roll": _("roll"), "pitch": _("pitch")}

#: the run's states (its state machine's), for the state line's reason
STATE_REASONS = {"pre-test": _("equalisation pre-test")}

#: the prechecks' names (``benchctl.run.prechecks``, ``session``, ``fitness``)
PRECHECKS = {
    "disk space": _("disk space"), "profile within limits": _("profile within the limits"),
    "stand answers": _("the stand answers"), "instrument answers": _("the instrument answers"),
    "serial match": _("the serial matches the unit's"),
    "stand ready and at rest": _("the stand is ready and at rest"),
    "instrument streams": _("the instrument streams"),
    "static agreement": _("stand and instrument agree at rest"),
    "stand at zero": _("the stand is at zero"), "mounting": _("the unit's mounting"),
    "host latency": _("the computer's timing"),
}

#: outcomes, as a plan's step or the run's own messages name them
OUTCOMES = {
    "PASS": _("PASS"), "FAIL": _("FAIL"), "INCONCLUSIVE": _("INCONCLUSIVE"),
    "ABORTED": _("ABORTED"), "ERROR": _("ERROR"), "SKIPPED": _("SKIPPED"),
    "NOT_JUDGED": _("NOT JUDGED"),
}

#: a plan's action statuses (``benchctl.plan.result.ActionResult``)
ACTION_STATUSES = {
    "ok": _("done"), "declined": _("answered no"), "unanswered": _("not answered"),
    "interrupted": _("interrupted"), "failed": _("failed"), "skipped": _("skipped"),
}

#: fixed messages of the run and of a plan (``fitness.SKIP_*``, ``session``, ``plan.runner``)
FIXED_MESSAGES = {
    "bringing the stand to zero": _("Bringing the stand to zero."),
    "bringing the stand to rest and closing the recording":
        _("Bringing the stand to rest and closing the recording."),
    "simulated time: host latency not measured":
        _("Simulated time: the computer's timing is not measured."),
    "host latency not measured: run.host_check.enabled is false":
        _("The computer's timing is not measured (switched off in the bench config)."),
    "starting the simulators for the plan": _("Starting the simulators for the plan."),
}

#: messages of a known beginning: the panel's sentence, the rest of the run's text its detail
#: (tried before the prechecks' forms, and after the cleanup steps' form, as they stand)
_PREFIXED_FIRST = (("ABORTED: ", _("ABORTED.")), ("recording to ", _("Recording to the folder:")))
_PREFIXED_LATER = (
    ("mounting check: ", _("Mounting check: each axis tilted a few degrees and back.")),
    ("equalisation pre-test: ", _("Equalisation pre-test.")),
    ("simulated disturbances: ", _("Simulated disturbances.")),
)

# the panel's own
REATTACHED = _("The panel was restarted and took this run up again; its earlier messages are "
               "in the run's log.")
DETAILS = _("Details")


class Words:
    """The texts of one language: ``w(msgid, **values)`` translates and fills in."""

    def __init__(self, lang: str = "en") -> None:
        self.lang = lang
        self.t = translations(lang)

    def __call__(self, msgid: str, **values: Any) -> str:
        text = self.t.gettext(msgid)
        return text % values if values else text

    def number(self, value: Any, digits: int, signed: bool = False) -> str:
        """``value`` with ``digits`` decimals in the language's way (``+3,000`` in Russian);
        "—" for no number."""
        from babel.numbers import format_decimal  # Babel: the optional web extra

        if not isinstance(value, int | float) or value != value:
            return "—"
        zeros = "0" * digits
        fmt = f"0.{zeros}" if digits else "0"
        if signed:
            fmt = f"+{fmt};-{fmt}"
        return str(format_decimal(value, format=fmt, locale=self.lang))

    def axis(self, name: str) -> str:
        return self(AXES[name]) if name in AXES else name

    def _prefixed(self, s: str, table: tuple[tuple[str, str], ...]) -> dict[str, str] | None:
        """``s`` told by the first of ``table``'s beginnings it starts with (None: none)."""
        for prefix, msgid in table:
            if s.startswith(prefix):
                return {"text": self(msgid), "detail": s[len(prefix):]}
        return None

    def precheck(self, name: str) -> str:
        """A check before the motion by its name, as the operator reads it."""
        return self(PRECHECKS[name]) if name in PRECHECKS else name

    def outcome_word(self, outcome: Any) -> str:
        o = str(outcome or "")
        return self(OUTCOMES[o]) if o in OUTCOMES else o

    # ------------------------------------------------------------------ an abort
    def abort_headline(self, abort: Mapping[str, Any], reason: str) -> str:
        """What stopped the run, in one sentence: from the abort's kind, source and error (the
        exception's class); the run's reason (English) only to tell apart the safety checks
        that share one class."""
        kind = str(abort.get("kind") or "")
        source = str(abort.get("source") or "")
        error = str(abort.get("error") or "")
        why = _after_source(reason, source)
        stand = abort.get("stand") or {}
        if kind == "operator" or source == "signal":
            sig = re.search(r"\bSIG[A-Z]+\b", reason)
            if sig is None or sig.group(0) == "SIGINT":
                return self(_("Stopped by the operator (Stop, or Ctrl-C at the terminal)."))
            if sig.group(0) == "SIGHUP":
                return self(_("Stopped: the terminal that started the run was closed (SIGHUP)."))
            return self(_("Stopped by a signal from the computer (%(signal)s)."),
                        signal=sig.group(0))
        if error == "PlanTimeout":
            return self(_("The plan's time limit ran out."))
        if error == "StandFault" or "E-stop" in why or why.startswith("stand reports fault"):
            if stand.get("estop") or "E-stop" in why:
                return self(_("The stand's emergency stop (E-stop) was pressed."))
            code = stand.get("fault_code") or _int(re.search(r"fault code (\d+)", why))
            if code:
                return self(_("The stand reported fault %(code)s."), code=code)
            return self(_("The stand reported a fault."))
        instrument = "instrument" in source
        if error == "ConnectionLost":
            return self(_("The connection to the instrument was lost.") if instrument
                        else _("The connection to the stand was lost."))
        if error == "DeviceTimeout":
            return self(_("The instrument did not answer in time.") if instrument
                        else _("The stand did not answer in time."))
        if error in ("ProtocolError", "ModbusException"):
            return self(_("The instrument's messages could not be read.") if instrument
                        else _("The stand answered with an error."))
        if error == "PrecheckFailed" or why.startswith("precheck "):
            m = re.match(r"precheck '([^']+)'", why)
            name = m.group(1) if m else ""
            if name in PRECHECKS:
                return self(_("A check before the motion failed: %(check)s."),
                            check=self(PRECHECKS[name]))
            return self(_("A check before the motion failed."))
        if source.startswith("recording") or error == "RecordingError":
            if "disk full" in why:
                return self(_("The disk is full: the recording could not be written."))
            return self(_("The recording could not be written."))
        for prefix, text in _SAFETY:
            if why.startswith(prefix):
                return self(text)
        if " did not finish within " in why:
            return self(_("The motion did not finish in time."))
        if kind == "software":
            return self(_("A software error stopped the run."))
        if kind == "equipment":
            return self(_("The equipment stopped the run."))
        return self(_("The run was aborted."))

    def abort_advice(self, abort: Mapping[str, Any], reason: str) -> str:
        """What to do before the next test, by the abort's kind."""
        kind = str(abort.get("kind") or "")
        why = _after_source(reason, str(abort.get("source") or ""))
        if kind == "software":
            return self(_("Keep the recording and its log (benchctl.log) for the developers: "
                          "this is a fault of the software. Then start again."))
        if kind == "equipment":
            if why.startswith("instrument silent") or "instrument" in str(abort.get("source")):
                return self(_("Check the instrument's cable, power and connection, then start "
                              "again."))
            if str(abort.get("source") or "").startswith("recording"):
                return self(_("Make room on the disk of the runs' folder, then start again."))
            return self(_("Find and clear the cause (the details below name it), check the "
                          "unit's mounting and the stand, then start again."))
        return self(_("Before the next test: check the unit's mounting and the stand, then "
                      "start again."))

    def stand_sentence(self, stand: Mapping[str, Any]) -> str:
        """Where the abort left the stand, from ``abort.stand``'s fields: each axis's angle,
        at rest or moving, the servo, a fault, the E-stop, at zero or not."""
        if not stand:
            return ""
        if not stand.get("known"):
            if stand.get("commands"):
                return self(_("Where the stand is now is not known: it did not answer. Check "
                              "it with the command below."))
            return self(_("The stand was not connected: it has not moved."))
        axes = stand.get("axes") or {}
        where = ", ".join(
            f"{self.axis(str(a))} {self.number((v or {}).get('angle_deg'), 3, signed=True)}°"
            for a, v in axes.items())
        parts = [self(_("Stand: %(angles)s."), angles=where) if where else self(_("Stand:"))]
        parts.append(self(_("At rest.")) if stand.get("at_rest")
                     else self(_("MOVING.")))
        parts.append(self(_("Servo on.")) if stand.get("enabled") else self(_("Servo off.")))
        if stand.get("fault_code"):
            parts.append(self(_("Fault %(code)s."), code=stand["fault_code"]))
        if stand.get("estop"):
            parts.append(self(_("E-stop pressed.")))
        if stand.get("at_zero"):
            parts.append(self(_("At zero.")))
        else:
            parts.append(self(_("NOT at zero.")))
        return " ".join(parts)

    # ------------------------------------------------------------------ live messages
    def message(self, text: str) -> dict[str, str]:
        """A live message of the run: ``text`` (the panel's words, "" when it has none for
        it) and ``detail`` (the run's own words it keeps, verbatim)."""
        s = text.strip()
        if s in FIXED_MESSAGES:
            return {"text": self(FIXED_MESSAGES[s]), "detail": ""}
        m = re.fullmatch(r"(PASS|FAIL|INCONCLUSIVE|NOT_JUDGED): recording closed", s)
        if m:
            return {"text": self(_("%(verdict)s: the recording is closed."),
                                 verdict=self.outcome_word(m.group(1))), "detail": ""}
        shown = self._prefixed(s, _PREFIXED_FIRST)
        if shown is not None:
            return shown
        m = re.fullmatch(r"precheck (.+?): (ok|FAILED) — (.*)", s, re.S)
        if m:
            name = self.precheck(m.group(1))
            ok = m.group(2) == "ok"
            return {"text": self(_("Check before the motion: %(check)s — passed.") if ok else
                                 _("Check before the motion: %(check)s — FAILED."),
                                 check=name), "detail": m.group(3)}
        m = re.fullmatch(r"precheck (.+?): (.*); measuring again \((\d+)/(\d+)\)", s, re.S)
        if m:
            name = self.precheck(m.group(1))
            return {"text": self(_("Check before the motion: %(check)s — measuring again "
                                   "(%(n)s of %(of)s)."), check=name, n=m.group(3),
                                 of=m.group(4)), "detail": m.group(2)}
        m = re.fullmatch(r"(\S.*?): (ok|FAILED)(?: (.*?))?(?: \(at the (.*)\))?", s, re.S)
        if m and text.startswith("  "):  # a cleanup step of an abort (session._abort)
            ok = m.group(2) == "ok"
            detail = (m.group(1) + (f": {m.group(3)}" if m.group(3) else "")
                      + (f" (at the {m.group(4)})" if m.group(4) else ""))
            return {"text": self(_("Cleanup step done.") if ok else _("Cleanup step FAILED.")),
                    "detail": detail}
        shown = self._prefixed(s, _PREFIXED_LATER)
        if shown is not None:
            return shown
        m = re.fullmatch(r"step (.+?): (PASS|FAIL|INCONCLUSIVE|ABORTED|ERROR|SKIPPED)"
                         r"(?: \((.*)\))?", s, re.S)
        if m:
            return {"text": self(_("Step %(step)s: %(outcome)s."), step=m.group(1),
                                 outcome=self.outcome_word(m.group(2))),
                    "detail": m.group(3) or ""}
        m = re.fullmatch(r"(setup|cleanup) (\d+): (ok|declined|unanswered|interrupted|failed|"
                         r"skipped)(?: — (.*))?", s, re.S)
        if m:
            status = self(ACTION_STATUSES[m.group(3)])
            text_ = (self(_("Setup action %(n)s: %(status)s."), n=m.group(2), status=status)
                     if m.group(1) == "setup" else
                     self(_("Cleanup action %(n)s: %(status)s."), n=m.group(2), status=status))
            return {"text": text_, "detail": m.group(4) or ""}
        m = re.fullmatch(r"plan (.*); cleanup follows", s, re.S)
        if m:
            return {"text": self(_("The plan stops; its cleanup follows.")),
                    "detail": m.group(1)}
        m = re.fullmatch(r"step (.+?): (.+)", s, re.S)
        if m:  # a plan's step starting: its name and its profile's
            return {"text": self(_("Step %(step)s starts."), step=m.group(1)),
                    "detail": m.group(2)}
        return {"text": "", "detail": text}

    def state_reason(self, reason: str) -> dict[str, str]:
        """A state's reason: the panel's words when it knows it, else the run's as a
        detail."""
        if not reason:
            return {"text": "", "detail": ""}
        if reason in STATE_REASONS:
            return {"text": self(STATE_REASONS[reason]), "detail": ""}
        return {"text": "", "detail": reason}


    # ------------------------------------------------------------------ the form's refusals
    def refused_text(self, field: str, value: object, max_chars: int,
                     pattern: str | None = None) -> str:
        """Why ``value`` is refused as the ``field`` (``serial`` or ``operator``), in the
        panel's words (the checks of ``benchctl.text.check_text`` and the serial pattern,
        told apart here; their English is the detail)."""
        serial = field == "serial"
        s = value.strip() if isinstance(value, str) else None
        if not s:
            return self(_("Type or scan the serial number.") if serial
                        else _("Type the operator's name."))
        if "\x1d" in s:
            return self(_("The scan holds several fields (a GS1 code): scan the serial "
                          "number's field alone."))
        if any(unicodedata.category(c) in _REFUSED for c in s):
            return self(_("The serial number holds a character that cannot be shown: type or "
                          "scan it again.") if serial else
                        _("The name holds a character that cannot be shown: type it again."))
        if len(s) > max_chars:
            return self(_("The serial number is too long: at most %(n)s characters.") if serial
                        else _("The name is too long: at most %(n)s characters."), n=max_chars)
        if serial and pattern is not None:
            return self(_("The serial number is not of this station's form (%(pattern)s)."),
                        pattern=pattern)
        return self(_("The serial number is refused.") if serial else
                    _("The operator's name is refused."))


_REFUSED = frozenset(("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"))

#: the safety checks that stop a run (``SafetyAbort``), told apart by their reason's start
_SAFETY: tuple[tuple[str, str], ...] = (
    ("instrument silent", _("The instrument went silent: no sample in time.")),
    ("tracking error on", _("The stand did not follow its setpoint (tracking error).")),
    ("limit breach", _("The stand reached an angle limit.")),
    ("stand departs from the profile", _("The stand departed from the profile.")),
    ("stand loop stalled", _("The stand's control loop stalled.")),
    ("stand loop ended", _("The stand's control loop ended too early.")),
    ("cannot rejoin", _("The stand's trajectory queue ran empty and the motion could not go "
                        "on.")),
    ("buffered mode", _("The stand's trajectory queue is missing or ran empty.")),
    ("stopped while waiting for the stand", _("The stand's trajectory queue ran empty.")),
    ("stand not at rest", _("The stand did not come to rest after the motion.")),
    ("stand not ready", _("The stand is not ready.")),
    ("cleanup step", _("A step of the stand's cleanup failed.")),
)


def _after_source(reason: str, source: str) -> str:
    """The reason without its ``source: `` prefix (``benchctl.run.supervisor.Fault``)."""
    if source and reason.startswith(source + ": "):
        return reason[len(source) + 2:]
    return reason


def _int(m: re.Match[str] | None) -> int | None:
    return int(m.group(1)) if m else None
