from __future__ import annotations

from pathlib import Path

import pytest

from capsd.cli import main


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["sim", "--offline", "x", "--duration", "-5"], "must be a positive number"),
        (["list", "--timeout", "-1"], "must be a positive number"),
        (["tap", "cap/**", "--count", "-3"], "must not be negative"),
        (["tap", "cap/**", "--duration", "nan"], "must be a positive number"),
        (["bench", "detect", "--frames", "0"], "not allowed"),
        (["bench", "detect", "--track-hold", "-1"], "must be a positive number"),
        (["bench", "detect", "--max-candidates", "0"], "not allowed"),
        (["train", "calibrate", "--confidence", "both"], "invalid choice"),
        (["replay", "x.mcap", "--speed", "0"], "must be a positive number"),
        (["train", "detector", "--workers", "0"], "not allowed"),
    ],
)
def test_bad_numbers_on_the_command_line_are_usage_errors(
    argv: list[str], message: str, capfd: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert message in capfd.readouterr().err


def test_calibrate_writes_a_detector_copy_only_with_both_paths(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    detector = tmp_path / "sonar_detect.yaml"
    detector.write_text("site: tank\n")
    argv = ["calibrate", "x.mcap", "-o", str(tmp_path / "o.yaml"), "--detector-config"]
    assert main([*argv, str(detector)]) == 2
    assert "--detector-config and --detector-out go together" in capfd.readouterr().err
    assert not (tmp_path / "o.yaml").exists()
    # An output folder that is not there: said before any work, for either copy.
    elsewhere = tmp_path / "missing" / "d.yaml"
    assert main([*argv, str(detector), "--detector-out", str(elsewhere)]) == 2
    assert f"--detector-out {elsewhere}: no folder" in capfd.readouterr().err
    assert main(["calibrate", "x.mcap", "-o", str(elsewhere)]) == 2
    assert f"-o {elsewhere}: no folder" in capfd.readouterr().err


def test_tls_files_are_checked_before_joining(capfd: pytest.CaptureFixture[str]) -> None:
    assert main(["tap", "cap/**", "--tls", "/nonexistent/ca.pem", "c.pem", "k.pem"]) == 2
    assert "ca_certificate" in capfd.readouterr().err


def test_an_error_a_verb_does_not_catch_is_a_message_not_a_traceback(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    # A mission starting in the mockup's corner, 0.5 m deep: no ASV station can see it.
    plan = tmp_path / "corner.yaml"
    plan.write_text("name: corner\npoints:\n  - {position_m: [4.3, 0.5], depth_m: 0.5}\n")
    code = main(["demo", "--tank", "mockup", "--mission", str(plan), "--out", str(tmp_path)])
    err = capfd.readouterr().err
    assert code == 1
    assert "no ASV station in the mockup tank sees the plan's start" in err
    assert "Traceback" not in err
