"""``tests/_results.py``: the results files the studies and benchmarks write beside themselves."""

from __future__ import annotations

from pathlib import Path

from _results import Results, markdown_table


def test_a_rewritten_file_holds_the_header_and_the_last_run_only(tmp_path: Path) -> None:
    out = tmp_path / "r.md"
    for value in ("1", "2"):
        res = Results(__file__, "Title", out)
        res.note("setting: x")
        res.table(["a", "b"], [(value, "|")], title="Table")
        res.write()
    text = out.read_text(encoding="utf-8")
    assert text.startswith("# Title\n\n- command: `python tests/test_results_file.py")
    assert text.count("# Title") == 1 and "| 2 | \\| |" in text and "| 1 |" not in text
    for line in ("- setting: x", "- date: ", "- commit: ", "- machine: ", "## Table"):
        assert line in text


def test_append_mode_adds_one_section_per_run_under_one_title(tmp_path: Path) -> None:
    out = tmp_path / "r.md"
    out.write_text("# Old title\n\nWritten by hand.\n\n## earlier run\n\nkept\n", encoding="utf-8")
    for label in ("before", "after"):
        res = Results(__file__, "Title", out, append=True, label=label)
        res.table(["a"], [(label,)], title="Table")
        res.write()
        res.write()  # a second write of the same run replaces its section, adds none
    text = out.read_text(encoding="utf-8")
    assert text.startswith(
        "# Old title\n\nWritten by hand.\n\n## earlier run\n\nkept\n\n## before: "
    )
    assert text.count("## before: ") == 1 and text.count("## after: ") == 1
    assert text.index("## before: ") < text.index("## after: ")
    assert text.count("### Table") == 2 and "# Title" not in text


def test_append_mode_starts_a_new_file_with_its_title(tmp_path: Path) -> None:
    out = tmp_path / "sub" / "r.md"
    res = Results(__file__, "Title", out, append=True)
    res.commit = "abc1234"
    res.write()
    text = out.read_text(encoding="utf-8")
    assert text.startswith(
        "# Title\n\nWritten by `tests/test_results_file.py`; one section per run"
    )
    assert "\n## 20" in text and ", commit abc1234\n" in text


def test_markdown_table_escapes_pipes() -> None:
    assert markdown_table(["x"], [("a|b",)]) == "| x |\n|---|\n| a\\|b |"
