"""The default cell file with edits, for tests of other cells: `edited_cell(scara__l1_mm=400)` is its JSON with
scara.l1_mm set (a key path joined by `__`); `cell_file_with(path, scara={"l1_mm": 400})` writes it with whole
sections updated."""

from __future__ import annotations

import json
from pathlib import Path

from cell.cellconfig import default_cell_path


def edited_cell(**edits) -> dict:
    raw = json.loads(default_cell_path().read_text())
    for dotted, value in edits.items():
        d = raw
        *keys, key = dotted.split("__")
        for k in keys:
            d = d[k]
        d[key] = value
    return raw


def cell_file_with(path: Path, **sections) -> Path:
    raw = json.loads(default_cell_path().read_text())
    for section, values in sections.items():
        raw[section].update(values)
    path.write_text(json.dumps(raw))
    return path
