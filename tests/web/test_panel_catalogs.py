"""The web pages' message catalogs: in step with the texts in their sources (the station
panel's templates and script texts, the line view's templates), every one translated into
Russian, and read at run time from the package."""

from __future__ import annotations

import re

from babel.messages.extract import extract_from_dir
from babel.messages.pofile import read_po

from benchctl.web.i18n import DOMAIN, LOCALE_DIR, SCRIPT_TEXTS, script_texts, translations


def source_ids() -> set[str]:
    found = extract_from_dir(
        str(LOCALE_DIR.parent),
        method_map=[("**/i18n.py", "python"), ("**/line.py", "python"),
                    ("**/wording.py", "python"), ("**/station.py", "python"),
                    ("**/panelrun.py", "python"),
                    ("**/app.py", "python"),
                    ("**/templates/station/**.j2", "jinja2"),
                    ("**/templates/line/**.j2", "jinja2")],
        options_map={"**/templates/station/**.j2": {"extensions": "jinja2.ext.i18n"},
                     "**/templates/line/**.j2": {"extensions": "jinja2.ext.i18n"}},
    )
    return {str(msg) for _, _, msg, _, _ in found if isinstance(msg, str)}


def catalog_ids(lang: str) -> dict[str, str]:
    with (LOCALE_DIR / lang / "LC_MESSAGES" / f"{DOMAIN}.po").open("rb") as f:
        return {str(m.id): str(m.string) for m in read_po(f) if m.id}


def test_the_catalogs_hold_every_text_of_the_sources() -> None:
    ids = source_ids()
    assert set(SCRIPT_TEXTS.values()) <= ids
    for lang in ("en", "ru"):
        assert set(catalog_ids(lang)) == ids, (
            f"{lang}: out of step with the sources; see benchctl/web/babel.cfg (pybabel extract, "
            "pybabel update)")


def test_every_text_is_translated_into_russian() -> None:
    ru = catalog_ids("ru")
    assert [m for m, s in ru.items() if not s] == []
    for m, s in ru.items():  # the placeholders kept
        assert re.findall(r"%\(\w+\)s", m) == re.findall(r"%\(\w+\)s", s), m


def test_the_languages_at_run_time() -> None:
    assert translations("ru").gettext("Stop") == "Стоп"
    assert translations("en").gettext("Stop") == "Stop"
    ru = script_texts("ru")
    assert ru["PASS"] == "ГОДЕН" and ru["ABORTED"] == "ПРЕРВАНО"
