"""``benchmarks/ncu_lines.py``: Nsight Compute source-page CSVs summed per line and instruction."""

from __future__ import annotations

from benchmarks.ncu_lines import main, read_report

HEAD = ('"Line No","Source","Address","Source","Warp Stall Sampling (All Samples)",'
        '"Warp Stall Sampling (Not-issued Samples)","# Samples","Instructions Executed"\n')


def test_lines_are_summed_and_inlined_instructions_counted_once(tmp_path, capsys):
    """Two files; an instruction listed under two source lines (inlined) counts once in the
    totals; predicated instructions are counted under their mnemonic."""
    text = ('"File Path","/src/array.h"\n' + HEAD
            + '"444","if (i < 0) {","-","-","7","7","7","300"\n'
            + '"","","0x10","      ISETP.GE.AND P0, PT, R1, RZ, PT","3","3","3","100"\n'
            + '"","","...","...","-","-","-","-"\n'
            + '"","","0x20","      @!P0 IADD3 R1, R1, R2, RZ","4","4","4","200"\n'
            + '"File Path","/src/kernels.py"\n' + HEAD
            + '"12","x = a[i]","-","-","9","9","9","250"\n'
            + '"","","0x20","      @!P0 IADD3 R1, R1, R2, RZ","4","4","4","200"\n'
            + '"","","0x30","      LDG.E R4, desc[UR4][R2.64]","5","5","5","50"\n')
    path = tmp_path / "r.csv"
    path.write_text(text)
    lines, sass = read_report(path)
    assert lines[("array.h", "444")][:3] == [7.0, 300.0, 2]
    assert lines[("kernels.py", "12")][:3] == [9.0, 250.0, 2]
    assert sorted(m for m, _, _ in sass) == ["IADD3", "ISETP", "LDG"]
    assert sum(e for _, _, e in sass) == 350.0
    assert main([str(path), "--top", "2"]) == 0
    out = capsys.readouterr().out
    assert "SASS instructions 3, executed 3; warp instructions executed 350" in out
    assert "IADD3 57.1%" in out


def test_a_file_that_is_no_report_is_refused(tmp_path, capsys):
    path = tmp_path / "x.csv"
    path.write_text("a,b\n1,2\n")
    assert main([str(path)]) == 2
    assert "no SASS rows" in capsys.readouterr().err
    assert main([str(tmp_path / "missing.csv")]) == 2
