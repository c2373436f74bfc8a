"""benchmarks/ncu_budget.py: the batched target's instruction budget from an Nsight Compute page."""

from __future__ import annotations

import json

import pytest

from benchmarks.ncu_budget import ISSUE_PER_SM, budget, main, read_ncu

PAGE = """\
  floor_sweep_kernel_c6b17288_cuda_kernel_forward (100, 1, 1)x(256, 1, 1), Context 2, CC 9.0
    Section: Command line profiler metrics
    smsp__sass_thread_inst_executed.sum                        inst 4,000,000
    smsp__sass_thread_inst_executed_op_fadd_pred_on.sum        inst   100,000
    smsp__sass_thread_inst_executed_op_ffma_pred_on.sum        inst 1,000,000
    smsp__sass_thread_inst_executed_op_fmul_pred_on.sum        inst   500,000
    Section: GPU Speed Of Light Throughput
    SM Frequency                    Ghz         2.00
    Duration                         us       368.93
    Issue Slots Busy               %        43.33
    Registers Per Thread             register/thread              76
    # SMs                                         SM             100
    Achieved Occupancy                        %        33.46
"""


def test_the_page_is_read_and_the_budget_is_the_issue_rate_shared_out():
    ncu = read_ncu(PAGE)
    assert ncu["thread_instructions"] == 4e6 and ncu["ffma"] == 1e6 and ncu["fadd"] == 1e5
    assert ncu["sm_count"] == 100 and ncu["sm_ghz"] == 2.0 and ncu["registers"] == 76
    # 1,000 particles in the launch, garments of 50 vertices swept 10 times a frame
    b = budget(ncu, 1000.0, vertices=50, sweeps=10, batch=8, target=1e6)
    rate = 100 * ISSUE_PER_SM * 2e9  # 2.56e13 thread instructions / s
    assert b["issue_rate_thread_instr_per_s"] == pytest.approx(rate)
    assert b["budget_instr_per_particle_sweep"] == pytest.approx(rate / (1e6 * 500))
    assert b["instr_per_particle_sweep"] == pytest.approx(4000.0)
    assert b["fp32_instr_per_particle_sweep"] == pytest.approx(1600.0)
    assert b["ceiling_gf_s_all_instructions_full_issue"] == pytest.approx(rate / (500 * 4000.0))
    assert b["ceiling_gf_s_fp32_only_full_issue"] == pytest.approx(rate / (500 * 1600.0))
    # 8 garments at the FP32-only ceiling: a frame of 8 / ceiling seconds
    assert b["frame_ms_at_batch_fp32_only_full_issue"] == pytest.approx(8e3 * 500 * 1600.0 / rate)
    assert b["frame_ms_at_batch_target"] == pytest.approx(8e-3)


def test_a_frequency_in_megahertz_is_read_as_such():
    ncu = read_ncu(PAGE.replace("SM Frequency                    Ghz         2.00",
                                "SM Frequency                    Mhz     1,980.00"))
    assert ncu["sm_ghz"] == pytest.approx(1.98)


def test_a_page_without_the_metrics_or_with_two_launches_is_refused():
    with pytest.raises(ValueError, match=r"r\.txt: no 'smsp__sass_thread_inst_executed_op_ffma_pred_on.sum'"):
        read_ncu(PAGE.replace("op_ffma", "op_hfma"), "r.txt")
    with pytest.raises(ValueError, match="more than one kernel launch"):
        read_ncu(PAGE + PAGE)


def test_the_command_writes_the_budget_or_exits_2_naming_the_file(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("OUT", raising=False)
    monkeypatch.setattr("benchmarks.common.RESULTS", tmp_path / "results")
    page = tmp_path / "ncu.txt"
    page.write_text(PAGE)
    floor = tmp_path / "floor.json"
    floor.write_text(json.dumps({"vertices": 50, "target_garment_frames_per_s": 1e6,
                                 "batches": {"4": {"particles": 3000, "colors": 3, "sweeps_per_frame": 10}}}))
    assert main([str(page), str(floor), "--batch", "4", "--at", "8", "--tag", "_t"]) == 0
    out = json.loads((tmp_path / "results" / "ncu_budget_t.json").read_text())
    assert out["instr_per_particle_sweep"] == pytest.approx(4000.0)  # 4e6 over 1,000 particles a colour
    assert out["frame_ms_at_batch_target"] == pytest.approx(8e-3)
    capsys.readouterr()
    assert main([str(page), str(floor), "--batch", "16"]) == 2
    assert "floor.json" in capsys.readouterr().err
    assert main([str(tmp_path / "missing.txt"), str(floor), "--batch", "4"]) == 2
    assert "missing.txt" in capsys.readouterr().err
