"""The table of current figures that `make bench` writes into benchmarks/README.md."""

from doc_figures import REPO, benchmark

table = benchmark("figures_table")
README = REPO / "benchmarks" / "README.md"
GROWTH = {
    "network": {
        "growth": [
            {"agents": 4, "simulate_s": 1.84, "peak_rss_mib": 280.0},
            {"agents": 128, "simulate_s": 101.0, "peak_rss_mib": 8704.0},
        ]
    }
}


def test_the_readme_has_one_dated_table_between_the_markers():
    text = README.read_text()
    assert text.count(table.BEGIN) == 1 and text.count(table.END) == 1
    assert len(text.splitlines()) < 200
    rows = table.parse_rows(text.split(table.BEGIN)[1].split(table.END)[0])
    assert len(rows) >= 10
    assert all(len(cells) == len(table.HEADER) - 2 for cells in rows.values())
    assert all(cells[-1].startswith("20") for cells in rows.values())  # each row dated


def test_a_run_replaces_its_rows_and_keeps_the_others(tmp_path):
    path = tmp_path / "README.md"
    path.write_text(README.read_text())
    before = table.parse_rows(path.read_text())
    table.update(path, GROWTH, "3 hardware threads, 1.0 GiB memory", today="2031-01-02")
    text = path.read_text()
    after = table.parse_rows(text)
    key = ("network.py --growth-only", "128 agents, 2 rules, 60 s bags")
    assert after.pop(key) == ["101.0 s wall, 8.50 GiB peak", "", "", "2031-01-02"]
    key = ("network.py --growth-only", "4 agents, 2 rules, 60 s bags")
    assert after.pop(key) == ["1.8 s wall, 0.27 GiB peak", "", "", "2031-01-02"]
    before.pop(key)
    assert after == before  # the rows of the parts not run are kept, with their dates
    assert "Machine: 3 hardware threads, 1.0 GiB memory" in text
    assert text.split(table.END)[1] == README.read_text().split(table.END)[1]
    table.update(path, {}, "another machine")  # a run of nothing changes nothing
    assert path.read_text() == text
