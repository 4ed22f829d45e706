"""The operator's language: the panel's message catalogs (``locale/<lang>/LC_MESSAGES/
benchctl_panel.po``, shipped in the package) read and compiled when first asked for, and the
texts the page's script shows (``SCRIPT_TEXTS``) in that language.

English is the catalogs' source language: its catalog leaves every text as its message id. A
language without a catalog is an error, never English in its place. The catalogs are made
from the sources with pybabel (``babel.cfg`` says how); a test checks they are up to date.
"""

from __future__ import annotations

import functools
import gettext
import io
from pathlib import Path

from benchctl.errors import ConfigError

LOCALE_DIR = Path(__file__).parent / "locale"
DOMAIN = "benchctl_panel"


def _(text: str) -> str:
    """Marks a text for the catalogs (pybabel extract); translated where it is shown."""
    return text


#: the texts the page's script puts on the screen (the page's own are in its template)
SCRIPT_TEXTS = {
    "idle": _("ready"), "starting": _("starting"), "prechecks": _("prechecks"),
    "equalising": _("equalising"), "fade-in": _("fade-in"), "running": _("running"),
    "fade-out": _("fade-out"), "analysing": _("analysing"), "done": _("done"),
    "aborted": _("aborted"), "refused": _("refused"), "error": _("error"),
    "PASS": _("PASS"), "FAIL": _("FAIL"), "INCONCLUSIVE": _("INCONCLUSIVE"),
    "ABORTED": _("ABORTED"), "ERROR": _("NOT STARTED"),
    "settling": _("settling: judged after one period"), "within": _("within the limit"),
    "over": _("over the limit"), "not_judged": _("not judged live"),
    "limit": _("limit"), "stand": _("stand"), "instrument": _("instrument"),
    "missed_cycles": _("missed cycles"), "missed_polls": _("missed polls"),
    "rejoins": _("rejoins"), "underruns": _("underruns"), "samples": _("instrument samples"),
    "health_ok": _("healthy"), "health_warn": _("WARNING: the motion was touched"),
    "stopping": _("stopping: bringing the stand to rest…"),
    "next_commands": _("Bring the stand to rest at zero, in this order:"),
    "at_rest": _("The stand is at rest at zero."),
    "measured_before": _("Measured before the abort (not the run's result):"),
    "ci": _("95 % interval"), "connection_lost": _("connection to the panel lost: retrying…"),
    "serial_ok": _("serial accepted"),
    "open_report": _("Open the report"),
    "prompt_timeout": _("Not answered within %(s)s s, the plan ends (no answer is a no)."),
    "axis_roll": _("roll"), "axis_pitch": _("pitch"),
}


@functools.cache
def translations(lang: str) -> gettext.NullTranslations:
    """The catalog of ``lang``, compiled from its ``.po`` file."""
    po = LOCALE_DIR / lang / "LC_MESSAGES" / f"{DOMAIN}.po"
    if not po.is_file():
        raise ConfigError(f"no panel catalog for the language {lang!r} ({po})")
    from babel.messages.mofile import write_mo  # Babel: the optional web extra
    from babel.messages.pofile import read_po

    with po.open("rb") as f:
        catalog = read_po(f, locale=lang, domain=DOMAIN)
    buf = io.BytesIO()
    write_mo(buf, catalog)
    buf.seek(0)
    return gettext.GNUTranslations(buf)


def script_texts(lang: str) -> dict[str, str]:
    t = translations(lang)
    return {key: t.gettext(text) for key, text in SCRIPT_TEXTS.items()}
