"""CHAIN.toml: every key checked, clear errors naming the key, exit status of magcal run."""

import pytest

from magcal.chain import parse_chain_config
from magcal.cli import main
from magcal.errors import InputError

MINIMAL = '[input]\nfiles = ["raw/*.csv"]\ntarget = "fgmo"\n[position]\nlongitude_deg = 128.2\n'


def test_defaults_follow_the_contract():
    cfg = parse_chain_config(MINIMAL, "CHAIN.toml")
    assert cfg["offsets"] == {"kp_max": 1.0, "window_days": 28.0, "step_days": 7.0,
                              "method": "median", "min_used": 720, "cadence_s": 60.0,
                              "split_at_level_changes": False}
    assert cfg["alignment"]["reference"] == "model" and cfg["picog"]["plan"] == "auto"
    assert cfg["input"]["frame"] == "hpen" and cfg.kind == "geostationary"


@pytest.mark.parametrize("extra, message", [
    ("[offsets]\nwindow = 28\n", "unknown key 'window'"),
    ("[offset]\nkp_max = 1\n", "unknown section [offset]"),
    ("[offsets]\nkp_max = \"low\"\n", "kp_max must be"),
    ("[offsets]\nmethod = \"mean\"\n", "method 'mean'"),
    ("[model]\nname = \"T02\"\n", "T02"),
    ("[frames]\nto_common = { fgmo = \"estimate\" }\n", "needs reference"),
    ("[frames]\nto_common = { fgmo = [[1, 0], [0, 1]] }\n", "3x3 matrix"),
    ("[picog]\non_worse = \"ignore\"\n", "on_worse"),
    ("[spin]\nspin_period_s = 20\n", "does not apply to a spinning"),
])
def test_bad_keys_name_section_and_key(extra, message):
    with pytest.raises(InputError, match=message.replace("[", r"\[").replace("(", r"\(")):
        parse_chain_config(MINIMAL + extra, "CHAIN.toml")


def test_position_and_files_are_required():
    with pytest.raises(InputError, match="needs the key 'files'"):
        parse_chain_config("[input]\ntarget = 'a'\n[position]\nlongitude_deg = 1\n", "C.toml")
    with pytest.raises(InputError, match=r"\[position\] needs longitude_deg"):
        parse_chain_config('[input]\nfiles = ["a.csv"]\n', "C.toml")
    with pytest.raises(InputError, match="not valid TOML"):
        parse_chain_config("[input\n", "C.toml")


def test_run_exits_2_with_one_line_for_a_bad_configuration(tmp_path, capsys):
    cfg = tmp_path / "CHAIN.toml"
    cfg.write_text(MINIMAL)
    assert main(["run", str(cfg), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "matches no file" in err[0] and "CHAIN.toml" in err[0]
    assert main(["run", str(tmp_path / "missing.toml"), "-o", str(tmp_path / "o")]) == 2


def test_unsupported_input_is_exit_2_naming_the_file(tmp_path, capsys):
    (tmp_path / "raw").mkdir()
    (tmp_path / "raw" / "a.csv").write_bytes(b"\x00\x01garbage")
    cfg = tmp_path / "CHAIN.toml"
    cfg.write_text(MINIMAL)
    assert main(["run", str(cfg), "-o", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "a.csv" in err and "supported" in err
