"""Every option of every `cell` command is named in the README or docs/ (a walk-through found
`replay --json`, `grasp --step-mm/--gap-mm` and half of `run`'s options in no document)."""

import re
from pathlib import Path

from cell.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]


def test_every_long_option_is_named_in_the_readme_or_docs():
    texts = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    quoted = " ".join(q for f in texts for q in re.findall(r"`([^`]*)`", f.read_text()))
    named = set(re.findall(r"--[a-z0-9][a-z0-9-]*", quoted))
    parsers = build_parser()._commands
    assert len(parsers) > 20  # every command, the subcommands of calibrate, hw, bench and examples too
    missing = {" ".join(words): sorted(o for a in p._actions for o in a.option_strings
                                       if o.startswith("--") and o != "--help" and o not in named)
               for words, p in parsers.items()}
    assert not {k: v for k, v in missing.items() if v}, "options in no document (README.md, docs/*.md)"
