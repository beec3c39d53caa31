"""Bad recording directories, damaged recordings and concurrent example appends: each is a
clear error (exit 2), never a traceback, a wrong exit code or a lost or mixed-up file."""


from conftest import run_cli


def test_cell_run_refuses_to_record_into_a_non_empty_directory_and_leaves_it_alone(tmp_path, capsys):
    d = tmp_path / "notes"
    (d / "frames").mkdir(parents=True)
    (d / "decisions.jsonl").write_text('{"type": "mine"}\n')
    (d / "frames" / "000009.png").write_bytes(b"not a recording's frame")
    before = {p: p.read_bytes() for p in d.rglob("*") if p.is_file()}
    code, _, err = run_cli("run", "--record", d, capsys=capsys)
    assert code == 2 and "not empty" in err and "Traceback" not in err
    assert {p: p.read_bytes() for p in d.rglob("*") if p.is_file()} == before


def test_cell_run_record_where_nothing_can_be_written_is_bad_input(tmp_path, capsys):
    f = tmp_path / "a-file"
    f.write_text("x")
    code, _, err = run_cli("run", "--record", f / "session", capsys=capsys)
    assert code == 2 and "cannot write the recording" in err and "Traceback" not in err
    assert f.read_text() == "x"

