"""The line view's pages: the Jinja2 environment (autoescaping on, every text the user reads
through gettext) and the rendering of the line view.

``environment(translations)`` is the one place the page's language is chosen: it installs
``translations`` (any ``gettext.NullTranslations``, e.g. a ``gettext.GNUTranslations`` of a
catalogue) with ``jinja2.ext.i18n`` in new style — ``{{ _("… %(name)s", name=value) }}``,
the value escaped — and defaults to ``gettext.NullTranslations()``: English, as written.
"""

from __future__ import annotations

import gettext
import math
from collections.abc import Callable
from datetime import datetime
from functools import cache
from typing import Any

from jinja2 import Environment, PackageLoader, StrictUndefined

from benchctl.web.linechart import individuals_chart, moving_range_chart
from benchctl.web.linedata import LineView
from benchctl.web.linestats import CPK_TARGET, E2, RUN_LENGTH

LINE_TEMPLATE = "line/line.html.j2"


def _num(v: Any, spec: str = ".4g") -> str:
    """A number by ``spec``; ``—`` for none, NaN or infinity."""
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
        return "—"
    return format(v, spec)


def _pct(v: Any) -> str:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
        return "—"
    return f"{100.0 * float(v):.0f} %"


def _duration(seconds: Any) -> str:
    """Seconds as ``H:MM:SS`` (``—`` for none)."""
    if not isinstance(seconds, int | float) or not math.isfinite(float(seconds)):
        return "—"
    s = max(0, int(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


def _when(d: Any, form: str = "%Y-%m-%d %H:%M:%S") -> str:
    if isinstance(d, datetime):
        return d.strftime(form)
    if isinstance(d, str) and len(d) >= 19:
        return d[:19].replace("T", " ") if form != "%H:%M" else d[11:16]
    return "—"


def _make_environment(translations: gettext.NullTranslations) -> Any:
    env = Environment(
        loader=PackageLoader("benchctl.web", "templates"),
        autoescape=True,
        undefined=StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        extensions=["jinja2.ext.i18n"],
    )
    env.install_gettext_translations(translations, newstyle=True)  # type: ignore[attr-defined]
    env.filters.update(num=_num, pct=_pct, duration=_duration, when=_when)
    return env


@cache
def _default_environment() -> Any:
    return _make_environment(gettext.NullTranslations())


def environment(translations: gettext.NullTranslations | None = None) -> Any:
    """The pages' Jinja2 environment: autoescaping, ``StrictUndefined``, gettext in
    ``translations`` (None: ``gettext.NullTranslations()``, English as written; made once)."""
    if translations is None:
        return _default_environment()
    return _make_environment(translations)


def render_line(view: LineView, *, history_url: Callable[..., str], refresh_s: int = 10,
                env: Any = None, lang: str = "en") -> str:
    """The line view as HTML: self-contained (inline CSS and SVG, no script, no external
    resource). ``history_url(serial=…, station=…)``: the link to a history page;
    ``refresh_s``: the page reloads itself that often (0: never)."""
    charts = [{"chart": c, "i": individuals_chart(c), "mr": moving_range_chart(c)}
              for c in view.charts if c.points]
    return str((env or environment()).get_template(LINE_TEMPLATE).render(
        view=view, charts=charts, history_url=history_url, refresh_s=int(refresh_s),
        lang=lang, e2=E2, run_length=RUN_LENGTH, cpk_target=CPK_TARGET,
    ))


__all__ = ["LINE_TEMPLATE", "environment", "render_line"]
