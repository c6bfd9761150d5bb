"""`ns2 results` (`make results`): README's results table and the docs' tables are what the
command writes from the committed result files; the provenance stamp; the renderer on small
synthetic result files (an experiment without files is "not run", never a number)."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from click.testing import CliRunner

from ns2cli import main
from ns2codegen.results import command_line, commit, stamp
from ns2exp import tables
from ns2exp.blind import table

REPO = Path(__file__).resolve().parent.parent


def test_readme_and_docs_are_what_ns2_results_writes():
    r = CliRunner().invoke(main, ["results", "--check", "--root", str(REPO)])
    assert r.exit_code == 0, r.output
    readme = (REPO / "README.md").read_text()
    block = readme.split("<!-- results:begin -->")[1].split("<!-- results:end -->")[0]
    rows = [line for line in block.splitlines() if line.startswith("| ") and not line.startswith("| experiment")]
    assert len(rows) == len(tables.EXPERIMENTS)
    for e, row in zip(tables.EXPERIMENTS, rows):     # a row names its command, and its commits or "not run"
        assert f"`{e.command}`" in row, row
        assert re.search(r" at ([0-9a-f]{7}|commit not recorded)", row) or "no committed result" in row
    for e, row in zip(tables.EXPERIMENTS, rows):     # every commit a committed file (or its folder's record) names
        for rel in e.files:
            doc = tables.load(REPO, rel)
            assert doc is None or tables.origin(doc)[0][:7] in row, (rel, row)
    for t in tables.DOC_TABLES:
        assert f"<!-- results:{t.name}:begin -->\nMade by `" in (REPO / t.doc).read_text()


def _git(repo, *args):
    subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True)


def test_stamp_names_commit_command_and_date(tmp_path):
    doc = {"mse": 0.1 + 0.2, "rows": [1, 2]}
    s = stamp(doc, "make sim")
    assert {k: v for k, v in s.items() if k != "provenance"} == doc and "provenance" not in doc
    p = s["provenance"]
    assert p["command"] == "make sim" and re.fullmatch(r"[0-9a-f]{7}(-dirty)?", p["commit"]), p
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", p["date"])
    with pytest.raises(TypeError):
        stamp([1, 2])
    assert commit(tmp_path) == "unknown"                      # not a checkout
    repo = tmp_path / "repo"
    repo.mkdir()
    _git(repo, "init", "-q")
    (repo / "a.txt").write_text("a\n")
    _git(repo, "add", "a.txt")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "a")
    head = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True).stdout
    assert commit(repo) == head[:7]
    (repo / "new.txt").write_text("untracked\n")              # untracked files do not make it dirty
    assert commit(repo) == head[:7]
    (repo / "a.txt").write_text("b\n")
    assert commit(repo) == head[:7] + "-dirty"
    assert command_line([str(REPO / "cli" / "__main__.py"), "real", "blind", "--out", "a b.json"]) \
        == "ns2 real blind --out 'a b.json'"
    assert command_line([str(REPO / "benchmarks" / "ablation.py"), "--seeds", "3"]) == "benchmarks/ablation.py --seeds 3"


def _swaps(nn, bl):
    return {"swaps": 6, "tuning": {}, "simulator": "rough", "rows": [
        {"case": "L2S", "controller": "NN", "median_worst_z_error_m": nn, "max_worst_z_error_m": nn,
         "z_error_rms_m": nn / 3, "motor_cmd_rms": 0.02},
        {"case": "L2S", "controller": "BL-tuned", "median_worst_z_error_m": bl, "max_worst_z_error_m": bl,
         "z_error_rms_m": bl / 3, "motor_cmd_rms": 0.02}]}


def _checkout(tmp_path) -> Path:
    """A checkout with the generated blocks' markers and no result file."""
    root = tmp_path / "co"
    (root / "docs").mkdir(parents=True)
    (root / "README.md").write_text("# x\n\nbefore\n<!-- results:begin -->\nold row\n<!-- results:end -->\nafter\n")
    for doc in dict.fromkeys(t.doc for t in tables.DOC_TABLES):
        before = (root / doc).read_text() if doc == "README.md" else ""
        (root / doc).write_text(before + "".join(f"## {t.name}\n<!-- results:{t.name}:begin -->\n<!-- results:{t.name}:end -->\n"
                                        "text\n" for t in tables.DOC_TABLES if t.doc == doc))
    return root


def test_renderer_on_synthetic_results(tmp_path):
    root = _checkout(tmp_path)
    runs = root / tables.RUNS
    (runs / "sim").mkdir(parents=True)
    doc = stamp(_swaps(0.004, 0.012), "make sim")
    doc["provenance"]["commit"] = "abcdef1"
    (runs / "sim/swaps.json").write_text(json.dumps(doc))
    assert tables.write(root) == list(dict.fromkeys(["README.md", *(t.doc for t in tables.DOC_TABLES)]))
    readme = (root / "README.md").read_text()
    assert readme.startswith("# x\n\nbefore\n<!-- results:begin -->\n| experiment |") and (
        "<!-- results:end -->\nafter\n" in readme) and "old row" not in readme
    row = {e.key: line for e in tables.EXPERIMENTS for line in readme.splitlines() if line.startswith(f"| {e.title} |")}
    assert "L2S 0.40 vs 1.20 cm (3.00x)" in row["sim"] and "`make sim` at abcdef1" in row["sim"]
    assert "no committed result: `sim/rings.json`" in row["sim"]       # the file missing
    for key in ("calibrate", "planning", "paper-data", "ablation"):
        e = next(x for x in tables.EXPERIMENTS if x.key == key)
        assert f"| no committed result: `{e.command}` | - |" in row[key]
        assert not re.search(r"\d\.\d", row[key].split("|")[2])                    # no number made up
    flights = root / "docs/real-flights.md"
    assert "No committed result (`docs/results/runs/real/blind.json`)" in flights.read_text()
    # a result of before the stamps (its commit only where a doc records it), without its lags: refused
    (runs / "real").mkdir()
    old = json.loads((REPO / tables.RUNS / "real/memory.json").read_text())
    (runs / "real/memory.json").write_text(json.dumps({k: v for k, v in old.items() if k not in ("provenance", "lags_ms")}))
    with pytest.raises(tables.ResultsError, match="lags_ms"):
        tables.write(root)

    (runs / "real/memory.json").write_text(json.dumps(dict(json.loads((runs / "real/memory.json").read_text()),
                                                           lags_ms=[50, 100, 200])))
    tables.write(root)
    text = flights.read_text()
    assert "at commit not recorded; `docs/results/runs/real/memory.json`" in text
    assert "| collection 2020-06-16 left out | 11.53 +- 0.86 / 8.92 +- 0.29 |" in text
    assert "commit not recorded" in (root / "README.md").read_text()
    (runs / "real/provenance.json").write_text(json.dumps({"memory.json": {
        "provenance": {"commit": "1b959af", "command": "ns2 real memory"}, "source": "docs/x.md section 1"}}))
    tables.write(root)
    assert "Made by `ns2 real memory` at 1b959af (as docs/x.md section 1 records)" in flights.read_text()

    # deterministic, and --check says when a generated block was edited by hand
    assert tables.write(root, check=True) == []
    assert CliRunner().invoke(main, ["results", "--check", "--root", str(root)]).exit_code == 0
    (root / "README.md").write_text((root / "README.md").read_text().replace("3.00x", "3.10x"))
    r = CliRunner().invoke(main, ["results", "--check", "--root", str(root)])
    assert r.exit_code == 1 and "README.md" in r.output
    assert "3.10x" in (root / "README.md").read_text()                              # --check wrote nothing
    assert CliRunner().invoke(main, ["results", "--root", str(root)]).exit_code == 0
    assert "3.00x" in (root / "README.md").read_text()


def test_markers_and_collect(tmp_path):
    root = _checkout(tmp_path)
    (root / "README.md").write_text("no markers\n")
    r = CliRunner().invoke(main, ["results", "--root", str(root)])
    assert r.exit_code == 1 and "needs one <!-- results:begin -->" in r.output
    root = _checkout(tmp_path / "b")
    made = root / "build/sim/results"
    made.mkdir(parents=True)
    (made / "swaps.json").write_text(json.dumps(_swaps(0.01, 0.02)))             # not stamped: refused
    r = CliRunner().invoke(main, ["results", "--root", str(root), "--collect", "sim"])
    assert r.exit_code == 1 and "no provenance" in r.output
    assert not (root / tables.RUNS / "sim/swaps.json").exists()
    (made / "swaps.json").write_text(json.dumps(stamp(_swaps(0.01, 0.02), "make sim")))
    r = CliRunner().invoke(main, ["results", "--root", str(root), "--collect", "sim"])
    assert r.exit_code == 0, r.output
    assert (root / tables.RUNS / "sim/swaps.json").read_bytes() == (made / "swaps.json").read_bytes()
    assert "L2S 1.00 vs 2.00 cm (2.00x)" in (root / "README.md").read_text()
    assert CliRunner().invoke(main, ["results", "--root", str(root), "--collect", "nope"]).exit_code == 1


def test_blind_table_is_the_same_read_back():
    """The table of a blind result as scored (models in scoring order) equals the table of
    its JSON read back (keys sorted): the docs' generated tables are the run's."""
    res = json.loads((REPO / tables.RUNS / "real/blind.json").read_text())
    scored = json.loads(json.dumps(res))
    for s in list(scored["leave_one_collection_out"].values()) + [scored["held_out_flights"]]:
        s["models"] = {k: s["models"][k] for k in ("ours", "authors", "zero", "onboard") if k in s["models"]}
    assert table(scored) == table(res)
    assert table(res).splitlines()[2].startswith("| collection 2019-12-11 left out | ours (blind) |")


def test_rows_of_each_command_s_results():
    """Each experiment's row read off that command's own output (committed results of
    earlier rounds, docs/results/runs/; a calibration made up in its form): the numbers
    the hand-written rows of those rounds stated."""
    old = REPO / "docs/results/runs"
    read = lambda name: json.loads((old / name).read_text())  # noqa: E731
    sim = tables.sim_summary({"sim/swaps.json": read("sim/swaps.json"), "sim/rings.json": read("sim/rings.json")})
    assert "L2S 0.37 vs 1.15 cm (3.09x)" in sim and "5-robot rings: BL 8.1 / BL-tuned 1.4 / NN 1.4" in sim
    assert "16-robot three rings: BL 11.6 / BL-tuned 1.8 / NN 1.8" in sim
    abl = tables.ablation_summary({"ablation/ablation.json": read("ablation/ablation.json")})
    assert abl.startswith("validation MSE of H = 20, L = 4: 1.99 +- 0.01 g^2 (1,392,294 samples, 3 seeds)")
    assert "without relative velocity: +25 %" in abl and "type-agnostic: +25 % (teams of 4-5 robots +102 %)" in abl
    assert "the sum of pairwise models: +1 % (teams of 4-5 robots +2 %)" in abl and "H 10: 0 %, 40: 0 %" in abl
    plan = tables.planning_summary({"planning/plan.json": read("planning/plan.json")})
    assert plan.startswith("3D: NN 125 of 125 planned, 125 within the force limits in flight; BL 125 of 125 planned, "
                           "86 within") and "2D: NN 97 of 125 planned, 92 within" in plan
    pd = tables.paper_data_summary({"paper-data/paper_data.json": read("paper-data/paper_data.json")})
    assert pd.startswith("1,392,294 samples of the rough simulator; the network's validation MSE 2.08 g^2")
    cal = {"paper_l2s": {"BL-authors": {"median_worst_z_error_m": 0.161, "paper_m": 0.17},
                         "NN-authors": {"median_worst_z_error_m": 0.074, "paper_m": 0.07}}}
    assert tables.calibrate_summary({"calibrate/calibration.json": cal}).endswith(
        "BL-authors 16.1 cm (paper 17), NN-authors 7.4 cm (paper 7)")


def test_real_row_says_what_the_files_say():
    """The real row's words follow the numbers: a C mismatch, a memory that does not help."""
    cc = {"samples": 10, "float_mismatches": 0, "fixed_mismatches": 2,
          "selection_all_flights": {"samples": 20, "mismatches": 1}}
    row = tables.real_summary({"real/c_check.json": cc})
    assert "differs from the references in C on 0 (float) and 2 (fixed point) of 10" in row and "bit for bit" not in row
    assert "neighbour selection differs from the data's on 1 of 20" in row
    now, past = {"mean": 10.0, "std": 0.5}, {"mean": 10.4, "std": 0.5}
    mem = {"lags_ms": [50], "s": {"wake_neutral": {"now": now, "with_past": past}, "wake_lower_beyond_spread": False}}
    row = tables.real_summary({"real/memory.json": mem})
    assert "state 50 ms ago changes the blind wake MSE (mass-neutral) by +4 % (not beyond the seeds' spread) with s" in row


def test_docs_tables_carry_the_runs_numbers():
    """Each docs table made from a committed result (sim, planning, ablation, the real and
    simulated adaptation, the real data report) carries the numbers of the hand-written
    table it replaced, and names the command and commit of every file it is made of."""
    from ns2exp.simadapt import BATTERY_WINDOW_S

    block = {t.name: tables.doc_block(REPO, t) for t in tables.DOC_TABLES}
    for t in tables.DOC_TABLES:
        assert block[t.name].startswith("Made by `"), t.name
        for rel in (t.file, *t.more):
            doc = tables.load(REPO, rel)
            assert f"`docs/results/runs/{rel}`" in block[t.name] and tables.origin(doc)[0][:7] in block[t.name]
    assert "| L2S | 6.9 / 7.8 | 1.1 / 1.3 | 0.4 / 0.5 | 1.1 / 1.5 | 6.1 / 6.3 | 3.09 |" in block["sim-swaps"]
    assert "| L2S | 6.9 | 1.1 | 0.4 | 1.1 | 6.1 | 7.8 / 3.1 / 0.5 |" in block["readme-sim"]
    assert "| 16-robot three rings | 11.6 | 1.8 | 1.8 | 13.4 / 4.6 / 4.0 | 15 -> 10 |" in block["readme-sim"]
    assert "| BL-tuned (BL-tuned, NN): 33 of 42 candidates within the bound | Lp = 4.5 / 4.5 / 8.4 1/s" in block["sim-tuning"]
    assert "| z error rms (cm) | 2.1-6.4 | 0.3-0.9 | 0.2-0.4 | 0.5-2.5 | 1.7-25.9 |" in block["sim-noise"]
    assert "15 of 42 candidates within the bound | Lp = 3 / 3 / 2.5 1/s, Kv = 6 / 6 / 13.5" in block["sim-clean-tuning"]
    assert "| L2S | 7.8 / 8.9 | 3.1 / 3.4 | 0.5 / 0.5 | 1.2 / 1.2 | 6.7 / 6.9 | 6.61 |" in block["sim-clean-swaps"]
    assert "| 16-robot three rings | small* | 8.7 / 11.6 | 1.6 / 1.8 | 1.6 / 1.8 | 8.6 / 11.4 | 7.3 / 8.4 |" in block["sim-rings"]
    assert "| 5-robot rings | large | 2.9 / 4.6 | 1.0 / 1.2 | 0.8 / 0.9 | 2.0 / 2.1 | (BL) |" in block["sim-rings"]
    assert "| 2.08 | 0.79 | 3.44 | 0.48 | 0.49 |" in block["paper-data"]
    rows = [line for line in block["planning"].splitlines() if line.startswith("| 2D") or line.startswith("| 3D")]
    assert [r.split(" | ")[0] for r in rows[::2]] == [f"| {d} {c}" for d in ("2D", "3D")
                                                       for c in ("SL", "SS", "LL", "SSL", "SLL")]
    assert "| 2D SLL | NN | 3/25 | 3/3 | 4.2 / 9.3 | 4.8 g, 0/3 | 7.2 g, 0/3 | 5.6 / 1.6 |" in block["planning"]
    assert "| 2D SSL | NN | 19/25 | 18/19 | 4.4 / 8.2 | 6.1 g, 1/19 | 7.7 g, 0/19 | 4.5 / 1.3 | 30 / 21 |" in block["planning"]
    assert "| large under large | -18.5 / -26.6 | -22.4 / -23.0 | -19.9 / -18.6 |" in block["planning-model"]
    assert ("| H = 20, L = 4 (the paper's network) | **1.993 +- 0.006** | 2.002, 1.990, 1.988 | 14, 16, 11 | "
            "3.77 +- 0.19 | **6.42 +- 0.18** |") in block["ablation"]
    assert ("| without relative velocity | 2.494 +- 0.022 (+25 %) | 2.464, 2.504, 2.515 | 12, 18, 14 | "
            "6.49 +- 0.30 (+72 %) | 7.60 (+18 %) |") in block["ablation"]
    assert "| type-agnostic deep set | 2.491 +- 0.040 (+25 %) |" in block["ablation"]
    assert "| H = 10 | 1.990 +- 0.042 (0 %) |" in block["ablation"]
    assert "| L2S after 4 s alone | 1.31 | 0.50 | 0.61 | 99-100 % |" in block["sim-adapt"]
    assert f"no payload: first {BATTERY_WINDOW_S:.0f} s | 0.90 | 0.37 | 0.39 | 100 % |" in block["sim-adapt"]
    assert "| NN+adapt at 428199a | NN+adapt at 2176e6a |" in block["sim-adapt-gate0"]
    assert "| L2S, the paper's swap | 0.44 | 0.44 | 0.53 | 99-100 % |" in block["sim-adapt-gate0"]
    laws = [line.split(" | ")[1] for line in block["real-adapt"].splitlines() if line.startswith("| held-out flights |")]
    assert laws[:4] == ["static (NN alone)", "bias (the default law)", "bias, neighbour gate (gateNbr 1)", "bias + scale"]
    assert ("| held-out flights | bias, forget 0.98 | 2.29 +- 0.07 | 2.23 +- 0.03 | 6.37 +- 0.55 | 5.86 +- 0.23 | "
            "+33 % (+32, +35, +32) |") in block["real-adapt"]
    assert block["real-adapt-types"].splitlines()[4].startswith("| held-out flights | 7.39 / 5.03 | 13.49 / 12.14 |")
    assert "| collection 2019-12-20 left out | 18.69 +- 0.48 | 3.92 +- 0.01 |" in block["real-adapt-masses"]
    assert ("| bias, neighbour gate (gateNbr 1) | 15.77 / 6.37 | 1.36 / 18.03 / 41.42 s, never 16 of 45 | "
            "4.45 / 15.22 / 26.68 s, never 21 of 45 |") in block["real-adapt-offset"]
    # data_report.json's own "source" (the authors' data) is not taken for the doc recording its commit
    assert "records)" not in block["hover"].splitlines()[0] and "data_report.json" in block["hover"].splitlines()[0]
    assert "| type-agnostic deep set, without the held-out flights | - | 6.03 +- 0.18 | 6.96 +- 0.08 |" in block["real-ablation"]
    assert "| H = 20, L = 4, every flight, the paper's protocol | 6.42 +- 0.18 | 3.33 +- 0.09 | - |" in block["real-ablation"]
    assert "| all | **32.07 g** | **62.53 g** | |" in block["hover"]
    assert "| 2019-12-11/swap_ll/02 | cf101, cf102 | setpoint events | -8.3, +8.3 | 1.9 | - | 59.8 |" in block["flights"]
    # the Cortex-M4 benchmarks and the ground truth's calibration (README's and the docs' tables once written by hand)
    assert ("| fixed, sliced, worst 500 Hz tick (4 phi per tick, 4 ticks) + controller | 213.5 us | 291.7 us | "
            "224.1 us |") in block["cycles"]
    assert "| on-board variant, fixed, one iteration + controller | 310.0 us | 406.0 us (over 400) | 329.7 us (14.2 KB) |" \
        in block["cycles"]
    assert "| cycles per MAC, fixed, whole prediction (60,840 MACs) | 1.558 | 2.066 | 1.606 |" in block["cycles"]
    assert "fixed 583 / 771 / 604 us: **over budget** (the machine's bound is 412 us" in block["bench-target"]
    assert "fixed 310 / 406 / 330 us: **within budget at zero wait and SRAM only**" in block["bench-target"]
    assert "| full prediction with 1 / 4 / 16 neighbours (+ environment), zero wait | fixed 118 / 221 / 589 us" \
        in block["bench-target"]
    assert ("fixed point 771 us for 15 neighbours + controller in one tick (604 us with its hot tables in SRAM; the "
            "machine's bound is 412 us: over the 400 us budget), 292 us in the worst 500 Hz tick") in block["readme-measures"]
    assert "adds 5.7 % of 1 ms to the firmware's worst stabilizer iteration" in block["readme-measures"]
    assert "7 of the paper's 8 points within their tolerance" in block["readme-measures"]
    assert "11.93 vs 11.4 (Fig. vis (g))" in block["readme-measures"]
    assert "| small under small | -12.4 | -10.6 | -9.0 | -6.7 | -3.9 | -2.8 | -2.1 |" in block["gaps"]
    assert "| 5.00 | 0.0 % | 2 % | fitted |" in block["calibration"]
    assert "| 2-D SSL NN | 6.31 / 0.97 | 6.50 | 8.75 / 3.41 | 2.57 |" in block["scp-programs"]
    assert "| 537 s, 41,730 samples/s, validation MSE 0.186 g^2 (label variance 37 g^2) |" in block["bench-host"]
    assert "parametrized 0.84 s, **5.7x**; Stage 1 + 2 per trial 7.74 -> 3.75 s, **2.1x**" in block["bench-host"]
    assert "| 22.5 (1 robot), 3.5 (16 robots): a 60 s 16-robot flight in 17 s |" in block["bench-host"]
    assert "| all 16 trials | 4.83 / 0.84 | **5.74** | 7.74 / 3.75 | **2.06** |" in block["scp-programs"]
    assert "| with the app, `NS2_INFER=fixed` (default) | +63,772 B (63.8 KB) | +4,092 B | +96 B |" in block["app-sizes"]
    assert "| difference | +4,296 B | **+11,016 B** | +11,016 B | |" in block["app-memory-sizes"]
    assert ("| whole prediction, zero wait / memory model, tables in flash | 94,778 / 125,722 cycles (564 / 748 µs) | "
            "116,999 / 150,849 cycles (696 / 898 µs) |") in block["wake-memory-cycles"]
    assert "| 32,816 B, fits | 35,504 B, does not fit |" in block["wake-memory-cycles"]
    assert "| phi tables in SRAM (`NS2_TABLES=ram`) | 371,944 B | 121,276 B (9,796 free) | +24,060 B |" in block["app-sram"]


def test_sim_tuning_noise_and_paper_data_tables():
    """make sim's gain search and noise tables and make paper-data's table read what the
    files say; a swaps.json whose tuning is not its gain search's is refused."""
    t = {"Lp_xy": 3.0, "Lp_z": 5.6, "Kv_xy": 6.0, "Kv_z": 9.0}
    cands = [{**t, "median_worst_z_error_m": 0.0123, "hover_motor_cmd_rms": 0.0251, "admissible": True},
             {**t, "Kv_z": 30.0, "median_worst_z_error_m": 0.009, "hover_motor_cmd_rms": 0.04, "admissible": False}]
    search = {"tuning": t, "hover_noise_limit": 0.0274, "candidates": cands}
    rows = [{"case": c, "controller": k, "z_error_rms_m": z, "motor_cmd_rms": n}
            for c, k, z, n in (("S2S", "BL", 0.021, 0.011), ("L2S", "BL", 0.05, 0.03), ("S2S", "NN", 0.002, 0.025))]
    out = tables.sim_tuning_table({"tuning": t}, search)
    assert "bound 2.74)" in out and "| Lp = 2 / 2 / 2.5 1/s, Kv = 4 / 4 / 4 N s/m per kg |" in out
    assert out.endswith("1 of 2 candidates within the bound | Lp = 3 / 3 / 5.6 1/s, Kv = 6 / 6 / 9 N s/m per kg "
                        "| 1.23 | 2.51 |")
    with pytest.raises(ValueError):
        tables.sim_tuning_table({"tuning": {**t, "Kv_z": 30.0}}, search)
    noise = tables.sim_noise_table({"rows": rows}).splitlines()
    assert noise[0] == "| swaps, range over the cases | BL | NN |"
    assert noise[2:] == ["| z error rms (cm) | 2.1-5.0 | 0.2-0.2 |", "| motor-command noise (% PWM rms) | 1.1-3.0 | 2.5-2.5 |"]
    pd = {"data": {"samples": 1000, "simulator": "rough", "teams": 9, "scenarios": 12, "flight_seconds_per_team": 700.0,
                   "generation_s": 60.4},
          "training": {"epochs": 20, "train_samples": 800, "train_time_s": 5.0, "validation_mse_g2": 2.0912,
                       "label_variance_g2": 10.15, "validation_mse_per_scenario_g2": {"S": 0.766, "L->S": 0.455}},
          "ablation": {"epochs": 5, "H": {"20": 2.114, "10": 2.137, "40": 2.109}, "W": {"40/25": 2.114, "24/16": 2.073}}}
    lines = tables.paper_data_table(pd).splitlines()
    assert lines[0].startswith("1,000 labelled samples of the rough simulator: 9 teams flying the 12 scenarios")
    assert "| overall | S | L->S |" in lines and "| 2.09 | 0.77 | 0.46 |" in lines
    assert lines[-1] == "| 10 2.14, 20 2.11, 40 2.11 | 24/16 2.07, 40/25 2.11 |"


def test_sim_adapt_flies_make_sim_s_committed_gain_search():
    """`ns2 sim adapt`'s default BL-tuned gains are those of make sim's committed gain
    search (one file, the one docs/simulator.md's table reads), not a copy beside it."""
    from ns2cli.simexp import GAIN_SEARCH

    assert GAIN_SEARCH == REPO / tables.RUNS / "sim/gain_search.json" and GAIN_SEARCH.is_file()
    swaps = tables.load(REPO, "sim/swaps.json")
    assert json.loads(GAIN_SEARCH.read_text())["tuning"] == swaps["tuning"]
