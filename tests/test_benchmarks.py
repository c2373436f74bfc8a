"""Every maintained benchmark runs: each script as a subprocess at its smallest CPU setting,
writing its JSON (the date, the command line, the machine and its figures) to a temporary
folder. The figures are checked for what the scene guarantees, never for timings."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def run_benchmark(module: str, *args: str, results: Path | None = None, timeout: float = 900.0):
    """``python -m benchmarks.<module> ARGS [--results DIR]`` from the repository root:
    (the completed process, the parsed JSON results by file name)."""
    cmd = [sys.executable, "-m", f"benchmarks.{module}", *args]
    if results is not None:
        cmd += ["--results", str(results)]
    env = {k: v for k, v in os.environ.items() if k != "OUT"}
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=env)
    found = {p.name: json.loads(p.read_text()) for p in sorted(results.glob("*.json"))} if results else {}
    return proc, found


def single_result(module: str, *args: str, tmp_path: Path) -> dict:
    """The one JSON result of a benchmark run that must succeed, with its common fields checked."""
    proc, found = run_benchmark(module, *args, results=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert len(found) == 1, sorted(found)
    (name, result), = found.items()
    assert name == f"{result['benchmark']}.json"
    assert result["command"].startswith(f"python -m benchmarks.{module} ")
    assert result["machine"]["device"].startswith("cpu") and result["machine"]["warp"]
    assert result["date"][:2] == "20"
    return result


@pytest.mark.slow
def test_lbs(tmp_path):
    r = single_result("bench_lbs", "--device", "cpu", "--frames", "8", "--repeats", "1", tmp_path=tmp_path)
    assert r["benchmark"] == "lbs_cpu" and r["sizes"]["frames"] == 8
    assert r["sizes"]["vertices"] == 13348 and r["figures"]["device_frames_per_s"] > 0


@pytest.mark.slow
def test_cloth_core_drops_the_sheet_onto_the_sphere(tmp_path):
    r = single_result("bench_cloth", "--device", "cpu", "--n", "11", "--frames", "3", "--self-contact",
                      tmp_path=tmp_path)
    assert r["benchmark"] == "cloth_core_cpu" and r["sizes"]["cloth_vertices"] == 121
    assert r["sizes"]["config"]["self_contact"]["enabled"] is True
    fig = r["figures"]
    assert fig["single_finite"] and "batched" not in fig  # batches run on CUDA only
    # six frames of 1/30 s: the sheet, 5 cm above the sphere, has fallen onto it, not through it
    assert 0.29 < fig["single_min_radius_m"] < 0.35


@pytest.mark.slow
def test_tshirt_walk(tmp_path):
    r = single_result("bench_tshirt", "--device", "cpu", "--vertices", "500", "--motions", "walk",
                      "--seconds", "0.1", tmp_path=tmp_path)
    assert r["benchmark"] == "tshirt_cpu"
    assert 400 < r["sizes"]["garment_vertices"] < 650 and r["sizes"]["substeps"] == 12
    ours = r["figures"]["walk"]["ours"]
    # 0.1 s at 30 fps: 3 output frames, the first the blend's end, so 2 timed solver frames
    assert ours["frames"] == 2 and ours["quality"]["finite"]
    assert ours["sequences_failing_gates"] == (1 if ours["failed_gates"] else 0)


@pytest.mark.slow
def test_sweep_runs_the_population_it_draws(tmp_path):
    r = single_result("sweep_tshirt", "--device", "cpu", "--vertices", "500", "--motions", "walk",
                      "--seconds", "0.1", "--settings", "2x2", "--population", "3", "--population-seed", "4",
                      tmp_path=tmp_path)
    assert r["benchmark"] == "tshirt_sweep_cpu"
    (row,) = r["settings"]
    assert (row["substeps"], row["iterations"]) == (2, 2)
    pop = row["population"]
    assert pop["size"] == 3 and len(pop["members"]) == 3 and 0 <= pop["passing"] <= 3
    labels = r["population"]
    assert labels[:2] == ["walk", "run"]  # the benchmark's own motions first
    name, *params = labels[2].split()
    drawn = dict(p.split("=") for p in params)
    assert name == "walk" and 1.0 <= float(drawn["speed"]) <= 1.8 and 0.7 <= float(drawn["arm_swing"]) <= 1.4
    assert row["passes"] == (pop["passing"] == 3 and not row["motions"]["walk"]["failed_gates"])


def test_sweep_refuses_a_setting_it_cannot_read(tmp_path):
    proc, found = run_benchmark("sweep_tshirt", "--device", "cpu", "--settings", "12by5", results=tmp_path)
    assert proc.returncode == 2 and not found
    assert proc.stderr.strip().splitlines()[-1].endswith("error: --settings: cannot read '12by5' "
                                                         "(SUBSTEPSxITERATIONS, e.g. 12x5)")


@pytest.mark.slow
def test_dataset_generation(tmp_path):
    r = single_result("bench_dataset", "--device", "cpu", "--sequences", "1", "--seconds", "0.1",
                      "--batch", "1", "--cases", "coarse", "--resolution", "0.07", tmp_path=tmp_path)
    case = r["figures"]["coarse"]
    assert all(v < 400 for v in case["vertices"])  # 7 cm edges: a few hundred vertices
    assert case["sequences"] == 1 and case["accepted"] + case["rejected"] == 1
    assert case["sequences_per_hour"] > 0
    assert r["warmup_s"] > 0  # an untimed first job compiled the kernels
    # the file stores positions; a reader's derivation (timed apart) makes the rest
    assert case["derive_on_read_s"] > 0 and case["derived_bytes_per_frame"] > case["bytes_per_frame"]
    phases = case["phases"]  # where the time went, the simulation's parts under its rung
    for path in ("garments", "simulation rung 1/prelude/body separation", "simulation rung 1/steps", "judge",
                 "derive/base", "derive/wrinkle", "write"):
        assert phases[path]["calls"] >= 1 and phases[path]["s"] >= 0.0, path
    assert 0.0 < sum(p["self_s"] for p in phases.values()) <= case["wall_s"]
    assert phases["simulation rung 1/steps/solver"]["calls"] >= 1  # the solver's share of the steps
    # the only group simulated again alone: its 3 clip frames, and the job's wall time over its own
    alone = case["simulation_alone"]
    assert alone["fine_frames"] == 3 and alone["stopped"] in (0, 1)
    assert case["ratio_made"] == pytest.approx(alone["s"] / case["wall_s"])


@pytest.mark.slow
def test_dataset_generation_on_a_local_cluster(tmp_path):
    r = single_result("bench_dataset", "--device", "cpu", "--sequences", "2", "--seconds", "0.1",
                      "--batch", "1", "--cases", "coarse", "--resolution", "0.07", "--warmup", "0",
                      "--alone", "0", "--workers", "2", tmp_path=tmp_path)
    case = r["figures"]["coarse"]
    assert r["sizes"]["workers"] == 2 and case["sequences"] == 2
    assert case["phases"] is None and case["ratio_made"] is None  # timed in the workers, not here


@pytest.mark.slow
def test_losses(tmp_path):
    r = single_result("bench_losses", "--device", "cpu", "--batch", "1", "--vertices", "300",
                      "--repeats", "1", "--warmup", "0", "--search-repeats", "1", tmp_path=tmp_path)
    terms = r["figures"]["terms"]
    assert {"membrane", "bending", "collision_vertex", "sum_snug_hood", "sum_gsnet"} <= set(terms)
    assert all(t["warp"]["forward_backward_ms"] > 0 and "torch" in t for t in terms.values())
    assert set(r["figures"]["collision_search"]) == {"vertex_bvh", "vertex_brute", "face_bvh", "face_brute"}


@pytest.mark.slow
def test_wrinkle_inference(tmp_path):
    r = single_result("bench_wrinkles", "--device", "cpu", "--frames", "2", "--steps", "1", tmp_path=tmp_path)
    (row,) = r["figures"]["rows"]
    assert row["steps"] == 1 and row["frames"] == 2 and row["fps"] > 0
    assert r["sizes"]["garment"] == "t_shirt" and r["machine"]["torch"]


@pytest.mark.slow
def test_gsnet_against_the_simulator(tmp_path):
    r = single_result("bench_gsnet", "--device", "cpu", "--vertices", "700", "--seconds", "0.1",
                      "--joint-topk", "0,4", tmp_path=tmp_path)
    (row,) = r["figures"]["rows"]
    assert row["vertices"] > 500 and set(row["gsnet"]) == {"0", "4"}
    for k, g in row["gsnet"].items():
        assert g["frames"] == 3 and g["fps"] > 0
        assert row["speedup"][k] == pytest.approx(row["simulation"]["ms_per_frame"] / g["ms_per_frame"])


def test_wrinkle_tables_average_the_seeds(tmp_path):
    """``wrinkle_tables`` reads ``EVAL/<garment>-<row>-<split>/metrics.json``: the seeds of ours
    are averaged (mean and standard deviation), the step sweep goes to its own table."""
    runs = {"tshirt-base-test_id": 0.002, "tshirt-ours-s0-test_id": 0.001, "tshirt-ours-s1-test_id": 0.003,
            "tshirt-ours-steps20-test_id": 0.004}
    for name, ev in runs.items():
        (tmp_path / "eval" / name).mkdir(parents=True)
        summary = {"ev": ev, "ecd": ev * ev, "normal_fd": 1e-4}
        record = {"split": "test_id", "summary": summary}
        (tmp_path / "eval" / name / "metrics.json").write_text(json.dumps(record))
    out, js = tmp_path / "tables.md", tmp_path / "tables.json"
    proc, _ = run_benchmark("wrinkle_tables", str(tmp_path / "eval"), "--out", str(out), "--json", str(js))
    assert proc.returncode == 0, proc.stderr
    tables = json.loads(js.read_text())
    mean, std, n = tables["tshirt"]["test_id"]["ours"]["ev"]
    assert n == 2 and mean == pytest.approx(0.002) and std == pytest.approx(0.001)
    assert tables["steps"]["20"]["ev"] == pytest.approx(0.004)
    text = out.read_text()
    assert "| ours, strain-norm conditioning (shipped) (2 seeds) | 2 ± 1 |" in text
    assert "| base mesh alone | 2 |" in text and "### DDIM steps" in text


def test_wrinkle_tables_gain_the_deepwrinkles_rows(tmp_path):
    """DeepWrinkles' evaluations (``scripts/train_deepwrinkles.sh``) give its row of Guo et al.'s
    tables and its own Table 1: pixel errors x 100 by training temporal term and LR input."""
    runs = {"t_shirt-deepwrinkles-test_id": 0.10, "t_shirt-dw_registration-test_id": 0.05,
            "t_shirt-dw_notemp_registration-test_id": 0.06, "t_shirt-dw_bs200-test_id": 0.08,
            "t_shirt-dw_release-test_id": 0.12}
    for name, l1 in runs.items():
        (tmp_path / "eval" / name).mkdir(parents=True)
        summary = {"ev": 0.02, "ecd": 3e-4, "nm_l1": l1, "nm_l2": l1 / 2, "nm_temporal": l1 * 0.9}
        record = {"split": "test_id", "summary": summary}
        (tmp_path / "eval" / name / "metrics.json").write_text(json.dumps(record))
    out = tmp_path / "tables.md"
    proc, _ = run_benchmark("wrinkle_tables", str(tmp_path / "eval"), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    text = out.read_text()
    assert "| DeepWrinkles (Lähner et al. 2018; global shape from the body) | 20 | 300 |" in text
    # the shipped-size model is a row of Guo et al.'s tables, not a column of the paper's Table 1
    assert "| DeepWrinkles, shipped size (16 filters, k = 200, 2 LSTM layers) | 20 | 300 |" in text
    assert ("| | Eq. 4 / Registr. | no temp / Registr. | Eq. 4 / BS 200 | Eq. 4 / Regre. |") in text
    assert "| Data (L1) | 5 | 6 | 8 | 10 |" in text and "| Temporal (Eq. 4) | 4.5 | 5.4 | 7.2 | 9 |" in text


def test_gsnet_tables_split_by_garment_and_ablation(tmp_path):
    """``gsnet_tables`` reads ``EVAL/<row>-<split>/metrics.json``: per-garment means of the
    sequences, the simulation's physics row from the ``*_gt`` figures, the unseen designs tagged
    and the ablations in their own table."""
    def seq(garment, ev):
        return {"garment": garment, "metrics": {"ev": ev, "edge_abs": 0.05, "edge_abs_gt": 0.01,
                                                 "normal_angle": 0.3, "normal_angle_gt": 0.2,
                                                 "collision": 0.02, "collision_gt": 0.001}}
    for row, scale in (("gsnet", 1.0), ("gsnet_noreg", 2.0), ("skinned_mlp", 3.0)):
        seqs = [seq("t_shirt", 0.01 * scale), seq("t_shirt", 0.03 * scale), seq("hoodie", 0.05 * scale)]
        summary = {k: float(np.mean([s["metrics"][k] for s in seqs])) for k in seqs[0]["metrics"]}
        (tmp_path / "eval" / f"{row}-test_ood").mkdir(parents=True)
        (tmp_path / "eval" / f"{row}-test_ood" / "metrics.json").write_text(
            json.dumps({"split": "test_ood", "summary": summary, "sequences": seqs}))
    out, js = tmp_path / "tables.md", tmp_path / "tables.json"
    proc, _ = run_benchmark("gsnet_tables", str(tmp_path / "eval"), "--out", str(out), "--json", str(js),
                            "--unseen", "hoodie")
    assert proc.returncode == 0, proc.stderr
    text = out.read_text()
    assert "| GSNet | 30 | 5 | 17.2 | 2 |" in text and "| simulation | – | 1 | 11.5 | 0.1 |" in text
    assert "| t_shirt, 2 seq.: GSNet | 20 |" in text
    assert "| hoodie (unseen design), 1 seq.: GSNet | 50 |" in text
    assert "### Table 3: ablations, test_ood" in text
    assert "| without physical regression (the projection kept) | 60 |" in text
    rows = json.loads(js.read_text())["test_ood"]
    assert rows["skinned_mlp"]["garments"]["t_shirt"]["ev"] == pytest.approx(0.06)


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("newton") is None, reason="newton is not installed (optional)")
def test_newton_drops_a_sheet_onto_a_sphere(tmp_path):
    """``newton_ref``'s own check: Newton's ``SolverVBD`` on the scene it is given falls freely,
    rests on the sphere, and hangs its edges below the contact (it exits 1 otherwise)."""
    r = single_result("newton_ref", "--device", "cpu", tmp_path=tmp_path)
    fig = r["figures"]
    assert r["newton_version"].startswith("1.") and fig["finite"]
    assert fig["min_radius_m"] > 0.198 and fig["lowest_m"] < 0.15


@pytest.mark.slow
def test_garments_table_and_population(tmp_path):
    r = single_result("bench_garments", "--device", "cpu", "--designs", "t_shirt", "--shapes", "mean",
                      "--motions", "walk", "--resolution", "0.06", "--seconds", "0.2", "--prelude", "0.2",
                      "--population", "2", "--seed", "3", "--population-resolution", "0.07",
                      "--smoothing", "cg", "--material", "denim", "--material-param", "friction=0.25",
                      "--design-param", "fit=loose",
                      "--design-param", "sleeve_length=0.3", "--frames-out", str(tmp_path / "frames"),
                      "--frames-every", "4", tmp_path=tmp_path)
    assert r["benchmark"] == "garments_cpu" and r["sizes"]["edge_m"] == 0.06 and r["complete"]
    (garment,) = r["table"]["garments"]
    (row,) = r["table"]["rows"]
    assert (row["design"], row["shape"], row["motion"]) == ("t_shirt", "mean", "walk")
    assert (garment["material"], garment["fit"], garment["sleeve_length"]) == ("denim", "loose", 0.3)
    assert garment["friction"] == 0.25 and r["sizes"]["material_params"] == ["friction=0.25"]
    assert (row["material"], row["fit"], r["sizes"]["material"]) == ("denim", "loose", "denim")
    with np.load(tmp_path / "frames" / "t_shirt_mean_walk.npz") as z:  # every 4th frame and the last
        assert z["frames"].tolist() == [0, 4, 5] and z["garment"].dtype == np.float32
        assert z["garment"].shape == (3, row["vertices"], 3)
        assert z["body"].shape == (3, r["sizes"]["body_vertices"], 3)
        assert z["garment_faces"].max() == row["vertices"] - 1
        assert len(z["panel_ids"]) == len(z["garment_faces"])
        # the rest shape and the flat pattern's edge lengths give the strain the gates read
        from sim.quality import edge_strain

        worst = np.abs(edge_strain(z["garment"], z["rest"], z["garment_faces"], device="cpu",
                                   rest_lengths=z["rest_edge_lengths"])).max()
        assert 0 < worst <= row["quality"]["max_edge_strain"] + 1e-5  # the stored frames are some of them
        # the garment is worn in every frame: its centre within 10 cm of the body's, across
        g, b = z["garment"].astype(np.float32), z["body"].astype(np.float32)
        assert np.isfinite(g).all()
        assert np.linalg.norm(g.mean(1)[:, [0, 2]] - b.mean(1)[:, [0, 2]], axis=1).max() < 0.1
    assert row["vertices"] == garment["vertices"] and 100 < row["vertices"] < 400
    assert garment["seam_gap_mm"] <= 1.0 and garment["sewing_s"] > 0 and row["substeps"] == [12]
    # 0.2 s at 30 fps from the motion's first frame: 6 frames
    assert row["frames"] == 6 and row["max_edge_strain"] == row["quality"]["max_edge_strain"]
    assert row["passed"] == (not row["failed_gates"])
    assert 0 < row["wrinkle_rms_mm"] < 50 and 0 < row["wrinkle_p99_mm"] < 100
    assert 0 < row["covered_body_vertices"] < r["sizes"]["body_vertices"]
    assert 0 <= row["skin_through_1mm_max_pct"] <= row["skin_through_max_pct"] <= 100
    assert row["skin_through_mean_pct"] <= row["skin_through_max_pct"]
    summary = r["table"]["summary"]
    assert summary["sequences"] == summary["simulated"] == 1 and summary["passed"] == int(row["passed"])
    assert summary["wrinkle_rms_mm"]["median"] == row["wrinkle_rms_mm"]
    assert r["smoothing_check_mm"] < 1e-3  # conjugate gradients against the sparse LU
    pop = r["population"]
    assert pop["size"] == len(pop["members"]) == 2 and pop["seed"] == 3
    assert pop["passing"] == sum(m["passed"] for m in pop["members"])
    assert pop["pass_rate"] == pop["passing"] / 2
    for m in pop["members"]:
        assert m["motion"] in r["sizes"]["population_motions"]
        if "error" in m and "substeps" not in m:
            continue  # not sewn: reported, not simulated
        ladder = [12, 20, 24]
        assert m["substeps"] == ladder[:len(m["substeps"])]
        assert m["passed"] == (not m.get("failed_gates", ["stopped"]))
        assert m["passed"] or len(m["substeps"]) == 3  # a failing member went through the whole ladder


@pytest.mark.parametrize("args, message", [
    (["--material", "tweed"], "--material: unknown preset 'tweed'; expected one of "),
    (["--design-param", "inseam=0.7"],
     "--design-param: 'inseam=0.7': expected KEY=VALUE with KEY a parameter of one of the table's designs"),
    (["--design-param", "fit=baggy"], "--design-param: t_shirt: "),
    (["--material-param", "stiffness=2"],
     "--material-param: material 'cotton': unknown field(s) ['stiffness']"),
])
def test_garments_refuses_a_bad_material_or_design_parameter(tmp_path, args, message):
    proc, found = run_benchmark("bench_garments", "--device", "cpu", "--designs", "t_shirt", *args,
                                results=tmp_path)
    assert proc.returncode == 2 and not found
    assert message in proc.stderr.strip().splitlines()[-1]


def test_garments_refuses_an_unknown_shape(tmp_path):
    proc, found = run_benchmark("bench_garments", "--device", "cpu", "--shapes", "mean,giant",
                                results=tmp_path)
    assert proc.returncode == 2 and not found
    assert proc.stderr.strip().splitlines()[-1].endswith(
        "error: --shapes: unknown 'giant'; expected mean, plus2, minus2, heavy, slim")


@pytest.mark.slow
def test_registration_against_the_simulation(sample_dataset, tmp_path):
    r = single_result("bench_registration", "--data", str(sample_dataset), "--sequences", "1",
                      "--frames", "2", "--variants", "default,no_tracking", "--device", "cpu",
                      tmp_path=tmp_path)
    assert r["benchmark"] == "registration_cpu" and r["sizes"]["frames"] == "consecutive"
    fig = r["figures"]
    assert list(fig) == ["skinned", "default", "no_tracking"]
    (row,) = r["per_sequence"]
    assert row["frames"] == [0, 1] and row["template_vertices"] in r["dataset"]["template_vertices"]
    n = row["group_vertices"]
    assert 0 < n["border"] <= n["band"] and n["band"] + n["interior"] == n["all"] == row["template_vertices"]
    # frame 0 has no frame before it: tracking starts it from the skinned template too, on the same scan
    tracked, alone = (row["variants"][v]["per_frame_mean_mm"] for v in ("default", "no_tracking"))
    assert tracked[0] == alone[0]
    for name, f in fig.items():
        a = f["all"]
        assert 0 < a["total_mean_mm"] <= a["total_p95_mm"] and a["surface_mean_mm"] >= 0, name
        # the normal and tangential parts split each vertex's squared error
        np.testing.assert_allclose(a["normal_rms_mm"] ** 2 + a["tangential_rms_mm"] ** 2,
                                   a["total_rms_mm"] ** 2, rtol=1e-6)
        if name != "skinned":
            assert 0 < f["paired_share"] <= 1 and f["s_per_frame"] > 0


@pytest.mark.parametrize("args, message", [
    (["--variants", "default,icp"], "--variants: unknown ['icp']"),
    (["--frames", "0"], "--frames and --sequences must be >= 1"),
])
def test_registration_refuses_bad_arguments(tmp_path, args, message):
    proc, found = run_benchmark("bench_registration", "--data", str(tmp_path), *args, results=tmp_path)
    assert proc.returncode == 2 and not found
    assert message in proc.stderr.strip().splitlines()[-1]
