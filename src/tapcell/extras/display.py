"""`[display]`: the printer's screen is not modelled; its options are kept as written, and
M117/M73 work (the `display_status` object a screen shows)."""

from __future__ import annotations

from tapcell.extras.display_status import load_display_status
from tapcell.host.config import ConfigSection


def load_config(section: ConfigSection, printer) -> None:
    section.config.mark_section_read(section.get_name())
    load_display_status(printer)
    return None
