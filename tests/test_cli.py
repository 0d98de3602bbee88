"""The magcal command: dispatcher, --help for every verb, --version, exit statuses."""

import subprocess
import sys

import pytest

from magcal import __version__
from magcal.cli import VERBS, main


def test_version_via_python_dash_m():
    out = subprocess.run([sys.executable, "-m", "magcal", "--version"], capture_output=True,
                         text=True, check=True)
    assert out.stdout.strip() == f"magcal {__version__}"


@pytest.mark.parametrize("verb", sorted(VERBS))
def test_every_verb_has_help(verb, capsys):
    with pytest.raises(SystemExit) as exc:
        main([verb, "--help"])
    assert exc.value.code == 0
    assert f"magcal {verb}" in capsys.readouterr().out


def test_usage_error_exits_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["no-such-verb"])
    assert exc.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


def test_no_verb_exits_2(capsys):
    assert main([]) == 2


def test_input_error_exits_2_with_one_line(tmp_path, capsys):
    # demo with a missing data folder is a bad-input case every build has
    status = main(["demo", "--data", str(tmp_path / "missing"), "-o", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1
    assert "data_samples/ not found" in err[0] and str(tmp_path / "missing") in err[0]


@pytest.fixture
def tiny(tmp_path):
    (tmp_path / "outdir").mkdir()
    data = tmp_path / "DATA.csv"
    data.write_text("time,Hp,He,Hn\n2019-11-01T00:00:00,1,2,3\n2019-11-01T00:01:00,1,2,3\n")
    (tmp_path / "products").mkdir()
    return tmp_path, data


@pytest.mark.parametrize("argv", [
    ["qc", "{data}", "-o", "{outdir}"],
    ["spincal", "{data}", "--spin-period", "4", "-o", "{outdir}"],
    ["report", "{products}", "-o", "{outdir}"],
    ["report", "{products}", "-o", "{d}/r.html", "--pdf", "{outdir}"],
    ["picog", "fit", "{data}", "--target", "fgmo", "--auto", "-o", "{outdir}"],
    ["offsets", "apply", "{data}", "--offsets", "{data}", "-o", "{outdir}"],
])
def test_output_that_is_a_directory_exits_2(tiny, capsys, argv):
    # sweep: qc, spincal, report and picog fit died with IsADirectoryError (exit 1)
    d, data = tiny
    args = [a.format(data=data, outdir=d / "outdir", products=d / "products", d=d)
            for a in argv]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"{d / 'outdir'}: is a directory, expected an output file" in err
    assert "internal error" not in err and not (d / "r.html").exists()
    assert [p.name for p in (d / "outdir").iterdir()] == []


def test_output_folder_verbs_still_take_a_directory(tiny, capsys):
    d, _ = tiny
    assert main(["demo", "--data", str(d / "missing"), "-o", str(d / "outdir")]) == 2
    assert "expected an output file" not in capsys.readouterr().err


def test_input_that_is_a_directory_is_named_so(tiny, capsys):
    d, data = tiny
    assert main(["offsets", "apply", str(d / "outdir"), "--offsets", str(data),
                 "-o", str(d / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert f"{d / 'outdir'}: is a directory, expected a file" in err
    assert "file not found" not in err
    assert main(["qc", str(d / "outdir"), "-o", str(d / "q.csv")]) == 2
    assert f"{d / 'outdir'}: is a directory, expected a file" in capsys.readouterr().err


@pytest.mark.parametrize("argv, option", [
    (["offsets", "fit", "{data}", "--kp", "{data}", "--window-days", "nan"], "--window-days"),
    (["offsets", "fit", "{data}", "--kp", "{data}", "--window-days", "inf"], "--window-days"),
    (["offsets", "fit", "{data}", "--kp", "{data}", "--window-days", "0"], "--window-days"),
    (["offsets", "fit", "{data}", "--kp", "{data}", "--window-days=-7"], "--window-days"),
    (["offsets", "fit", "{data}", "--kp", "{data}", "--step-days", "nan"], "--step-days"),
    (["qc", "{data}", "--range-nt", "-5"], "--range-nt"),
    (["qc", "{data}", "--range-nt", "0"], "--range-nt"),
])
def test_non_positive_or_non_finite_numbers_refused_at_parsing(tiny, capsys, argv, option):
    # sweep: --window-days nan/inf were internal errors (exit 1); qc --range-nt -5 flagged
    # every sample (exit 0)
    d, data = tiny
    args = [a.format(data=data) for a in argv] + ["-o", str(d / "out.csv")]
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}: must be a finite number > 0" in err
    assert not (d / "out.csv").exists()
