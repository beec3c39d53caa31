"""Bad inputs found by fuzzing the command line (a driver writing damaged files and running `cell ...`):
each is refused with exit 2 and one `cell: error:` line naming the file, never an internal error."""

import json

import pytest
from conftest import run_cli
from test_files import _example

from cell.examples import load_examples

DEEP = "[" * 100000 + "]" * 100000  # json's decoder recurses per level: RecursionError
DEEP_OBJECT = '{"a":' * 50000 + "1" + "}" * 50000


@pytest.mark.parametrize("line", [DEEP, DEEP_OBJECT], ids=["array", "object"])
def test_an_example_line_nested_too_deeply_is_bad_input(tmp_path, capsys, line):
    """Was: internal error (RecursionError), exit 1."""
    path = tmp_path / "ex.jsonl"
    path.write_text(json.dumps(_example("a").to_json()) + "\n" + line + "\n")
    code, out, err = run_cli("rules", "--examples", path, capsys=capsys)
    assert code == 2 and out == "" and "internal error" not in err, err
    assert err.strip() == f"cell: error: example file {path} line 2: not valid JSON (nested too deeply)"


@pytest.mark.parametrize("char", ["\u2028", "\u2029", "\x85"])
def test_an_example_line_holding_a_unicode_line_separator_is_one_line(tmp_path, char):
    """JSON strings may hold U+2028, U+2029 and U+0085 unescaped; str.splitlines() cut the line there and
    the file was refused as 'not valid JSON (Unterminated string ...)'."""
    a = _example("a").to_json()
    a["source"]["note"] = f"held{char}here"
    path = tmp_path / "ex.jsonl"
    path.write_text(json.dumps(a, ensure_ascii=False) + "\r\n" + json.dumps(_example("b").to_json()) + "\n",
                    encoding="utf-8")
    got = load_examples(path)
    assert [e.id for e in got] == ["a", "b"] and got[0].source["note"] == f"held{char}here"
