"""``adclient export`` and ``import`` with hostile text and hostile files, the real CLI in
a subprocess against a real ``adserver`` (issue 36): no exported cell reads as a
formula in a spreadsheet, yet an export imports back exactly; a CSV as Excel saves it
imports; a duplicate column, or JSON nested past any use, is a one-line error that
stores nothing."""

from __future__ import annotations

import csv
import json
import subprocess
from pathlib import Path
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from adclient import Client
from adclient.export import INERT_FIRST, formula_safe, unescaped
from adclient.importing import EXPORT_DEPTH
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import run_adclient

FORMULAS = [
    "=cmd|' /C calc'!A0",
    "+1+1",
    "-2+3",
    "@SUM(A1:A9)",
    "\t=1+1",
    "\r=1+1",
    "\uff1d1+1",  # a full-width equals sign
    "'quoted",
    "a;=1+1",  # a spreadsheet that splits on ';' must not see a cell "=1+1"
    "plain",
]
SPACE = {
    "type": "box",
    "params": [
        {"name": "x", "low": -5.0, "high": 5.0},
        {"name": "c", "type": "categorical", "choices": FORMULAS},
    ],
}


def failed_cleanly(result: subprocess.CompletedProcess[str], message: str, code: int = 1) -> None:
    """A one-line message on stderr, no traceback."""
    assert result.returncode == code, (result.stdout, result.stderr)
    assert message in result.stderr, result.stderr
    assert "Traceback" not in result.stderr + result.stdout
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr


def studies(client: Client) -> int:
    return len(client.studies())


def new_study(client: Client, name: str) -> int:
    return client.create_study(name=name, space=SPACE, proposer={"name": "random"}).id


def test_exported_cells_never_read_as_formulas_and_import_back(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    study = client.get_study(new_study(client, "formulas"))
    added = [
        study.add_trial({"x": -1.5 - index / 4, "c": choice}, -0.5 * index)
        for index, choice in enumerate(FORMULAS)
    ]
    failed = study.ask()
    failed.set_user_attr("note", "@SUM(1+1)*cmd|' /C calc'!A0")
    study.tell(failed, state="failed", message="-2+3+cmd|' /C calc'!A0")
    table = tmp_path / "trials.csv"
    exported = run_adclient(server, "export", str(study.id), "--output", str(table))
    assert exported.returncode == 0, exported.stderr

    # As a spreadsheet reads it: a bare cell is a number, so every text cell is quoted
    # (QUOTE_NONNUMERIC makes a float of each bare cell, and fails on bare text) ...
    with table.open(newline="", encoding="utf-8") as stream:
        rows: list[list[Any]] = list(csv.reader(stream, quoting=csv.QUOTE_NONNUMERIC))
    header, cells = rows[0], [dict(zip(rows[0], row, strict=True)) for row in rows[1:]]
    for text in (cell for row in rows for cell in row if isinstance(cell, str) and cell):
        assert text[0].isalnum() or text[0] in INERT_FIRST or text[0] == "'", repr(text)
    # ... numbers, negative ones too, stay bare numbers, and text that starts a formula
    # carries the quote that makes a spreadsheet read it as text.
    by_number = {int(row["number"]): row for row in cells}
    for trial in added:
        row = by_number[trial.number]
        assert row["value"] == trial.value and row["params_x"] == trial.params["x"]
        assert row["params_x"] < 0 and isinstance(row["params_x"], float)
    for trial, choice in zip(added, FORMULAS, strict=True):
        shown = by_number[trial.number]["params_c"]
        assert shown == (choice if choice in ("plain", "a;=1+1") else "'" + choice)
    assert by_number[failed.number]["message"] == "'-2+3+cmd|' /C calc'!A0"
    assert by_number[failed.number]["user_attrs_note"] == "'@SUM(1+1)*cmd|' /C calc'!A0"
    assert "user_attrs_note" in header

    # The import takes the quotes off again: the same params, values and message.
    target = new_study(client, "imported")
    imported = run_adclient(server, "import", str(table), "--study", str(target))
    assert imported.returncode == 0, imported.stderr
    again = client.trials(target)
    assert sorted((t.params["c"], t.params["x"], t.value) for t in added) == sorted(
        (t.params["c"], t.params["x"], t.value) for t in again if t.state == "complete"
    )
    assert [t.message for t in again if t.state == "failed"] == ["-2+3+cmd|' /C calc'!A0"]


@given(st.text())
def test_the_escape_is_formula_safe_and_undone_exactly(text: str) -> None:
    cell = formula_safe(text)
    assert unescaped(cell) == text
    assert not cell or cell[0].isalnum() or cell[0] in INERT_FIRST or cell[0] == "'"
    assert cell[:1] not in ("=", "+", "-", "@", "\t", "\r", "\uff1d")


def test_a_csv_as_excel_saves_it_imports(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    """A byte-order mark, CRLF line ends, and a choice Excel shows as text; a study file
    with a byte-order mark too."""
    table = tmp_path / "excel.csv"
    table.write_bytes('\ufeffx,c,value\r\n-1.5,plain,2.5\r\n0.5,"\'+1+1",-3\r\n'.encode())
    target = new_study(client, "from-excel")
    imported = run_adclient(server, "import", str(table), "--study", str(target))
    assert imported.returncode == 0, imported.stderr
    trials = sorted(client.trials(target), key=lambda t: t.number)
    assert [(t.params, t.value) for t in trials] == [
        ({"x": -1.5, "c": "plain"}, 2.5),
        ({"x": 0.5, "c": "+1+1"}, -3.0),
    ]
    study_file = tmp_path / "study.json"  # saved by a Windows editor, with a byte-order mark
    study_file.write_bytes(("\ufeff" + json.dumps({"name": "bom", "space": SPACE})).encode())
    submitted = run_adclient(server, "submit", str(study_file))
    assert submitted.returncode == 0, submitted.stderr
    assert "bom" in [study.name for study in client.studies()]


def test_a_column_named_twice_is_refused_naming_it(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    target = new_study(client, "duplicate-columns")
    twice = tmp_path / "twice.csv"
    twice.write_text("x,c,x,value\n1.0,plain,2.0,1.0\n")
    refused = run_adclient(server, "import", str(twice), "--study", str(target))
    failed_cleanly(refused, "the header names column 'x' twice")
    spelled = tmp_path / "spelled.csv"
    spelled.write_text("x,c,params_x,value\n1.0,plain,2.0,1.0\n")
    refused = run_adclient(server, "import", str(spelled), "--study", str(target))
    failed_cleanly(refused, "columns 'x' and 'params_x' name one param")
    assert client.study_info(target).n_trials == 0


def test_json_nested_past_any_use_is_a_clear_error(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    """Past the parser (a RecursionError in it), and within the parser but deeper than an
    export nests (near the stack's limit, sending it on could exhaust it): one line,
    exit 1, nothing stored."""
    before = studies(client)
    levels = 5000
    for name, deep in (("past", "[" * levels + "]" * levels), ("within", "[" * 900 + "]" * 900)):
        export = tmp_path / f"{name}.json"
        body = {"study": {"name": "deep", "space": SPACE, "metadata": {"k": "@"}}, "trials": []}
        export.write_text(json.dumps(body).replace('"@"', deep))
        refused = run_adclient(server, "import", str(export))
        failed_cleanly(refused, f"objects and arrays nest deeper than {EXPORT_DEPTH} levels")
    cell = tmp_path / "cell.csv"  # a column of no param of the space: its cells read as JSON
    cell.write_text(f"x,c,value,extra\n1.0,plain,1.0,{'[' * levels}{']' * levels}\n")
    target = new_study(client, "deep-cell")
    refused = run_adclient(server, "import", str(cell), "--study", str(target))
    failed_cleanly(refused, "line 2, extra: objects and arrays nest deeper than 32 levels")
    wide = tmp_path / "wide.csv"
    wide.write_text(f"x,c,value\n{'[' * levels}{']' * levels},plain,1.0\n")
    refused = run_adclient(server, "import", str(wide), "--study", str(target))
    failed_cleanly(refused, "line 2, x: '[[[[")
    assert len(refused.stderr) < 400  # the cell cut short, not 10,000 characters
    for suffix in ("json", "yaml"):  # a study file too (YAML's parser is recursive)
        study_file = tmp_path / f"study.{suffix}"
        study_file.write_text('{"name": "deep", "metadata": ' + "[" * levels + "]" * levels + "}")
        refused = run_adclient(server, "submit", str(study_file))
        failed_cleanly(refused, "objects and arrays nest")
    params = '{"x": ' + "[" * levels + "]" * levels + "}"
    refused = run_adclient(server, "enqueue", str(target), "--params", params)
    failed_cleanly(refused, "--params: objects and arrays nest deeper than 32 levels", code=2)
    assert studies(client) == before + 1 and client.study_info(target).n_trials == 0


def test_only_the_export_s_own_escape_comes_off() -> None:
    """A leading ``'`` before text that needs no escape was written so by hand."""
    assert [unescaped(cell) for cell in ("'abc", "'=1", "''abc", "'", "")] == [
        "'abc",
        "=1",
        "'abc",
        "'",
        "",
    ]


def test_a_yaml_study_file_reads_1e_3_as_a_number(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    """PyYAML reads ``1e-3`` (no dot) as text, which the API's strict numbers refuse; the
    CLI reads it as YAML 1.2 and JSON do, but the name and metadata as YAML 1.1 does (a
    commit ``7e12345`` stays text). A quoted number stays text, and is refused by name;
    a number past the float range is a one-line error, not a traceback."""
    study_file = tmp_path / "lr.yaml"
    study_file.write_text(
        "name: 2e3\nmetadata: {commit: 7e12345, at: 1e400}\nspace:\n  type: box\n  params:\n"
        "    - {name: lr, low: 1e-5, high: 1E-2, log: true}\n"
        "    - {name: n, type: int, low: 1, high: 2e2}\n"
        "    - {name: w, low: -.5e1, high: +.5e1}\n"
    )
    submitted = run_adclient(server, "submit", str(study_file))
    assert submitted.returncode == 0, submitted.stderr
    (study,) = [study for study in client.studies() if study.name == "2e3"]
    lr, n, w = study.space.params
    assert (lr.low, lr.high, n.high, w.low, w.high) == (1e-5, 1e-2, 200, -5.0, 5.0)
    assert study.metadata == {"commit": "7e12345", "at": "1e400"}
    before = len(client.studies())
    for name, params, message in (
        ("quoted", "{name: x, low: '0', high: 1}", "space"),
        ("huge", "{name: x, low: 0, high: 1e400}", "space.params[0].high is a number out of range"),
        ("inf", "{name: x, low: 0, high: .inf}", "space.params[0].high is a number out of range"),
    ):
        bad = tmp_path / f"{name}.yaml"
        bad.write_text(f"name: {name}\nspace:\n  type: box\n  params:\n    - {params}\n")
        refused = run_adclient(server, "submit", str(bad))
        failed_cleanly(refused, message)
    assert len(client.studies()) == before
