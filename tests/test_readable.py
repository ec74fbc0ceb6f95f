"""What a person reads from the CLI is written for a person (issue 39): no Python or SymPy repr
in the text output of trim, gains, envelope, simulate and montecarlo (tests/readable.py, the
same scanner that reads the PDF in test_report.py and SUMMARY.md in test_build.py), and the
messages say what happened."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from readable import raw_findings

from maglevgen.cli import main


def test_the_scanner_flags_each_raw_form_and_passes_what_a_person_writes() -> None:
    """Each form the issue names is flagged on a line of its own; the printed forms next to
    them (a decimal, a measured round-off, a note marker, a unit in brackets) are not."""
    raw = ["vanishes only at k = [1]", "u_phi = L_y * sum M_x", "trim: 8*F_lat*Lz**2*k",
           "K = [[1, 2], [3, 4]]", "Eq(x, 1) holds", "residual 1 - sqrt(2)",
           "u = 19.99999943 m/s", "y = -3.049314e-19 m"]
    for line in raw:
        assert len(raw_findings(line)) == 1, line
    fine = ["K1 = 0.119 (F_y1 - F_y2), u = 1.999999e+01 m/s", "max|ET - I| = 2.2e-16",
            "mass 9.3 kg paper [1]", "  [3] assumed (vehicle.inertia_cg)", "speed [m/s] 20",
            "sha256 e313d1f10e95f8fa..., version 0.1.0", "closed form (error 1.1e-16 vs 2e-9)"]
    assert raw_findings("\n".join(fine)) == []
    # a table of errors: its header makes a tiny number a measurement, in Markdown by column
    table = "| axis | final deviation | error |\n| --- | --- | --- |\n| y | 3e-19 m | 2e-16 |"
    assert [f.split(":")[1].strip() for f in raw_findings(table)] == ["3e-19 is round-off noise"]
    # a caption, then a page break (pdftotext: the page number, a form feed) before its table
    caption = "Largest relative gain error against the reference:\n"
    broken = "\n\n\n                 23\n\faxis   naive\nlateral  1.1e-10\nroll  2.1e-14"
    assert raw_findings(caption + broken) == []
    assert len(raw_findings("Gains at trim:\n" + broken)) == 1


@pytest.mark.slow  # about a minute on 2 busy cores: trim, gains and envelope sweep it
@pytest.mark.needs_cc
def test_the_cli_text_output_is_written_for_a_person(sim_lib, tmp_path: Path, capsys) -> None:
    """trim, gains, envelope, a launch, a hold below the envelope and a small Monte Carlo: their
    text output (stdout and stderr) has none of the raw forms; the launch says how long each
    run ran (a release ends it before --t-end), a hold outside [v_min, v_max] warns in one
    line, and the no-trim error of `trim` does not send the user to `maglevgen trim`."""
    runs = {
        "trim": ["trim"], "gains": ["gains"], "envelope": ["envelope", "--speeds", "12"],
        "launch": ["simulate", "--scenario", "launch", "--controller", "spec",
                   "--out", str(tmp_path / "launch")],
        "slow hold": ["simulate", "--speed", "5", "--t-end", "0.2", "--controller", "spec",
                      "--out", str(tmp_path / "slow")],
        "montecarlo": ["montecarlo", "--samples", "3", "--workers", "1", "--t-end", "0.2",
                       "--out", str(tmp_path / "mc")],
    }
    texts = {}
    for name, argv in runs.items():
        assert main(argv) == 0, name
        out = capsys.readouterr()
        texts[name] = out.out + out.err
        found = raw_findings(texts[name], name)
        assert found == [], "\n".join(found)
    launch = texts["launch"]
    assert "Simulated the launch from" in launch and "s of hold" not in launch
    ran = re.search(r"spec\s+\S+.*\(ran to t = (\S+) s\)", launch)
    assert ran and float(ran[1]) < 10.0, launch  # released before the default --t-end
    warnings = [ln for ln in texts["slow hold"].splitlines() if "warning" in ln]
    assert len(warnings) == 1 and "--speed 5 m/s is outside the envelope" in warnings[0]
    assert main(["trim", "--speed", "1"]) == 2
    err = capsys.readouterr().err
    assert "lift-off needs" in err and "see `maglevgen trim" not in err, err
    assert len(err.strip().splitlines()) == 1


def test_fmu_defaults_to_the_embedded_controller(monkeypatch, tmp_path: Path, capsys) -> None:
    """`maglevgen fmu` without --controller exports envelope.embedded_controller (what the
    firmware embeds and `build` verifies), with a --set override too; the FMU builder is
    replaced by a recorder (building one is test_fmu.py's)."""
    import maglevgen.exports.fmu as fmu

    seen = []
    monkeypatch.setattr(fmu, "build_fmu", lambda carriage, kind, controller, **kw:
                        seen.append(controller) or b"PK")
    assert main(["fmu", "--out", str(tmp_path / "a")]) == 0
    assert main(["fmu", "--out", str(tmp_path / "b"),
                 "--set", 'envelope.embedded_controller="coupled"']) == 0
    assert main(["fmu", "--out", str(tmp_path / "c"), "--controller", "lqr"]) == 0
    assert seen == ["spec", "coupled", "lqr"]
    assert "controller spec" in capsys.readouterr().out
