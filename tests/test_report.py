"""The HTML report: one self-contained file per campaign and per diagnosis, parsed, checked for
inline figures and no network, rendered in headless Chromium without console errors."""

import json
import re
import shutil
import subprocess
from pathlib import Path

import html5lib
import pandas as pd
import pytest

from campaign.cli import main
from campaign.reports.html import sha256_files
from campaign.validation.support import matrix_toml, one_line_error, pairs

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-logging=stderr",
    "--v=0",
    "--window-size=1280,1600",
]


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """A campaign with everything a report shows: two conditions gear up and down, identified,
    its replays flown (``campaign run`` writes the report at its end)."""
    folder = tmp_path_factory.mktemp("camp")
    (folder / "m.toml").write_text(matrix_toml(pairs((0, 0.3, [2000, 10000])), "report"))
    assert (
        main(["run", "--matrix", str(folder / "m.toml"), "--out", str(folder / "out"), "--jobs", "2", "--quiet"]) == 0
    )
    return folder / "out"


def parse(path: Path):
    """Parse strictly (a malformed document fails) and return the tree and the raw text."""
    text = path.read_text(encoding="utf-8")
    tree = html5lib.HTMLParser(strict=True, namespaceHTMLElements=False).parse(text)
    return tree, text


def assert_self_contained(tree, text: str) -> None:
    imgs = tree.findall(".//img")
    for img in imgs:
        assert img.get("src", "").startswith("data:image/"), img.get("src", "")[:60]
    for el in tree.iter():
        for attr in ("src", "href"):
            v = el.get(attr)
            if v is not None:
                assert v.startswith(("data:", "#")), (el.tag, v[:80])
    assert not tree.findall(".//script") and not tree.findall(".//link")
    assert not re.search(r"url\((?!['\"]?(data:|#))", text)  # no fetch from a stylesheet either


def render(path: Path, shot: Path) -> str:
    """Render the page in headless Chromium, take a screenshot; return its log."""
    res = subprocess.run(
        [
            CHROMIUM,
            *FLAGS,
            f"--user-data-dir={shot.parent / 'chromium-profile'}",
            f"--screenshot={shot}",
            path.resolve().as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    return res.stdout + res.stderr


def test_campaign_report_is_one_self_contained_page_in_part_60_form(campaign):
    path = campaign / "report.html"
    assert path.exists()  # written by run
    assert path.stat().st_size <= 10e6
    tree, text = parse(path)
    assert_self_contained(tree, text)
    sections = {s.get("id"): s for s in tree.findall(".//section")}
    assert {"coverage", "holds", "identification", "trace"} <= set(sections)
    assert tree.find(".//section[@id='coverage']//{http://www.w3.org/2000/svg}svg") is not None  # inline SVG
    # one page per replay case and loop, each with Part 60's items, its verdict as in metrics.csv
    metrics = pd.read_csv(campaign / "replays" / "metrics.csv")
    for (case, loop), rows in metrics.groupby(["case", "loop"]):
        page = sections[f"case-{case}-{loop}"]
        assert page.get("class") == "page"
        words = "".join(page.itertext())
        for item in (
            "Objective",
            "Initial conditions",
            "Driven or constrained",
            "Tolerances",
            "Validation data",
            "Result",
        ):
            assert item in words, (case, loop, item)
        for _, r in rows[rows.model != "reference"].iterrows():
            assert f"{r['model']}" in words
        verdicts = [s.text for s in page.iter("span") if s.get("class") in ("pass", "fail")]
        assert verdicts == ["PASS" if ok else "FAIL" for ok in rows[rows.model != "reference"].qtg_pass]
        assert page.find(".//img") is not None
    # the first page is the summary: each case and loop with each model's PASS/FAIL and smallest margin,
    # the test identifiers and a blank sign-off block; the navigation shows each case with its result
    first = tree.find(".//main/section")
    assert first.get("id") == "summary"
    summary = first.find(".//table")
    head = ["".join(th.itertext()) for th in summary.find(".//thead").iter("th")]
    assert head == [
        "case",
        "loop",
        "linear model",
        "linear: smallest margin",
        "nonlinear model",
        "nonlinear: smallest margin",
    ]
    shown = {}
    for tr in summary.find(".//tbody").iter("tr"):
        cells = ["".join(td.itertext()).strip() for td in tr.iter("td")]
        shown[cells[0], cells[1]] = cells[2:]
    expected = {}
    for r in metrics[metrics.model != "reference"].itertuples():
        margin = min(
            (3.0 - r.max_err_tas_kt) / 3.0,
            (100.0 - r.max_err_alt_ft) / 100.0,
            (r.tol_theta_deg - r.max_err_theta_deg) / r.tol_theta_deg,
        )
        expected.setdefault((r.case, r.loop), {})[r.model] = ("PASS" if r.qtg_pass else "FAIL", 100 * margin)
    assert set(shown) == set(expected)
    for key, cells in shown.items():
        for i, model in enumerate(("linear", "nonlinear")):
            verdict, margin = expected[key][model]
            assert cells[2 * i] == verdict, (key, model, cells)
            assert abs(int(cells[2 * i + 1].split(" %")[0]) - margin) < 1, (key, model, cells)
            assert (verdict == "PASS") == (margin >= 0)
    nav = "".join(tree.find(".//nav").itertext())
    for (case, loop), got in expected.items():
        assert f"{case} ({loop}) linear {got['linear'][0]} nonlinear {got['nonlinear'][0]}" in nav, nav
    identifiers = dict(
        zip(["".join(d.itertext()) for d in first.iter("dt")], ["".join(d.itertext()) for d in first.iter("dd")])
    )
    man = json.loads((campaign / "manifest.json").read_text())
    assert identifiers["campaign"] == man["campaign"] == "report"
    assert man["settings"]["matrix_sha256"][:16] in identifiers["matrix"]
    assert man["settings"]["aircraft_sha256"][:16] in identifiers["aircraft"]
    from infra.provenance import version

    assert man["tool"] == {"name": "gear-aero-id", "version": version()}
    assert identifiers["flown by"] == identifiers["report written by"] == f"gear-aero-id {version()}"
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC", identifiers["report written"])
    sign = first.find(".//table[@class='signoff']")
    rows = [["".join(td.itertext()).strip() for td in tr.iter("td")] for tr in sign.find(".//tbody").iter("tr")]
    assert rows == [["Prepared", "", "", ""], ["Checked", "", "", ""], ["Approved", "", "", ""]]
    assert ["".join(th.itertext()) for th in sign.iter("th")] == ["", "name", "signature", "date"]
    # traceable: the settings' hashes from the manifest, and the logs' hash recomputed
    assert man["settings"]["aircraft_sha256"] in text and man["settings"]["matrix_sha256"] in text
    assert sha256_files(sorted(campaign.glob("*.parquet"))) in text


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (.ci/run installs it)")
def test_reports_render_in_chromium_without_console_errors(campaign, tmp_path):
    shot = tmp_path / "first_page.png"
    log = render(campaign / "report.html", shot)
    assert "CONSOLE" not in log, [line for line in log.splitlines() if "CONSOLE" in line]
    data = shot.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000  # a page with content, not a blank
    # the diagnosis of the same campaign against its own bare model: nothing to name, still a report
    out = tmp_path / "diag"
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT

    assert (
        main(
            [
                "diagnose",
                "--data",
                str(campaign),
                "--model",
                str(DEFAULT_AIRCRAFT),
                "--out",
                str(out),
                "--no-plots",
                "--quiet",
            ]
        )
        == 0
    )
    tree, text = parse(out / "report.html")
    assert_self_contained(tree, text)
    verdict = tree.find(".//p[@class='verdict']").text
    doc = json.loads((out / "diagnosis.json").read_text())
    assert verdict.startswith(doc["verdict"])
    assert {"verdict", "causes", "compat", "rejected", "trace"} <= {s.get("id") for s in tree.findall(".//section")}
    assert doc["flown_together"] is None and tree.find(".//section[@id='verdict']/p[@class='note']") is None
    log = render(out / "report.html", tmp_path / "diagnosis.png")
    assert "CONSOLE" not in log
    # logs whose every Mach number is flown at one flap angle: the verdict carries the caution
    from diagnose.flap_mach import flown_together

    doc["flown_together"] = flown_together([(2000, 0.2, 30), (2000, 0.3, 0)])
    (out / "diagnosis.json").write_text(json.dumps(doc))
    assert main(["report", str(out)]) == 0
    tree, _ = parse(out / "report.html")
    note = tree.find(".//section[@id='verdict']/p[@class='note']")
    assert note is not None and note.text.startswith(
        "Caution: flap and Mach flown together (flap 30 deg only at Mach 0.2"
    )
    # a held-out log that leaves four times what the fitted ones do (three is told): the verdict says so too
    check = doc["held_out_check"]["CD"]
    assert not check["told"] and set(check["held_out_rms"]) == {Path(p).name for p in doc["data"]["held_out"]}
    worst = check["worst_log"]
    check.update(held_out_rms={**check["held_out_rms"], worst: 4.0 * check["fitted_worst_rms"]}, ratio=4.0, told=True)
    (out / "diagnosis.json").write_text(json.dumps(doc))
    assert main(["report", str(out)]) == 0
    tree, _ = parse(out / "report.html")
    notes = [p.text for p in tree.findall(".//section[@id='verdict']/p[@class='note']")]
    assert len(notes) == 2 and notes[1].startswith(f"Caution: the held-out data disagree in CD: {worst} leaves"), notes


def test_report_command_refreshes_and_refuses_what_is_not_a_result(campaign, tmp_path, capsys):
    before = (campaign / "report.html").stat().st_mtime_ns
    assert main(["report", str(campaign)]) == 0
    assert "report.html" in capsys.readouterr().out
    assert (campaign / "report.html").stat().st_mtime_ns >= before
    assert not list(campaign.glob(".report.html.partial"))
    (tmp_path / "empty").mkdir()
    one_line_error(capsys, ["report", str(tmp_path / "empty")], "neither a campaign folder")
    one_line_error(capsys, ["report", str(tmp_path / "missing")], "not a folder")
