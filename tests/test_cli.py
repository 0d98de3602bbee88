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
