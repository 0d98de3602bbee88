"""A messy copy of the ELFIN-A day, to run the chain on it as a user would.

The real FGS file (``../shared/real-data/elfin``, ELFIN SOC, PI V. Angelopoulos, UCLA:
"Open Data for Scientific Use") is written again to ``OUT`` with four faults of the
kinds instrument archives have, each in its own zone:

* zone 1: 40 single-sample spikes of +-2e5 counts (about 2000 nT) on random axes;
* zone 4: ``b3`` clipped at 95 % of its zone peak (saturation: the tops of the spin
  sine cut flat, 17 % of the zone);
* zone 7: every sample fill (``FILLVAL``, read as NaN);
* zone 9: 70 s of samples cut out 80 s before the zone's end, leaving a 10 s stub.

A configuration ``ELFIN_messy.toml`` beside it points at the copy and at the real state
file, so that::

    python workflows/elfin_messy.py /tmp/elfin-messy
    magcal run /tmp/elfin-messy/ELFIN_messy.toml -o /tmp/elfin-messy/run

calibrates it through the CLI. Expected: the spikes and the clipped tops flagged
(``used = 0``, counted per zone), zone 7 and the stub reported as not calibrated with
their rows delivered ``used = 0``, every other zone as on the clean day. The copy is
written outside the repository (the real data are never copied into it).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DATA = HERE.parent.parent / "shared" / "real-data" / "elfin"
FGS, STATE = "ela_l1_fgs_20220112_v01.cdf", "ela_l1_state_defn_20220112_v01.cdf"
FILL = -2147483648


def make_messy(counts: np.ndarray, t_s: np.ndarray, rng: np.random.Generator):
    """Counts (n, 3) with the four faults, the rows kept, and a line per fault."""
    from magcal.missions.elfin.phase import split_zones

    c = counts.astype(np.int64).copy()
    ranges = split_zones(t_s)
    keep = np.ones(len(c), bool)
    lines = []
    a, b = ranges[1]
    rows = rng.choice(np.arange(a + 100, b - 100), 40, replace=False)
    c[rows, rng.integers(0, 3, rows.size)] += rng.choice([-1, 1], rows.size) * 200_000
    lines.append(f"zone 1: 40 spikes of +-2e5 counts at rows {rows.min()}-{rows.max()}")
    a, b = ranges[4]
    cut = int(0.95 * np.abs(c[a:b, 2]).max())
    n_cut = int(np.sum(np.abs(c[a:b, 2]) >= cut))
    c[a:b, 2] = np.clip(c[a:b, 2], -cut, cut)
    lines.append(f"zone 4: b3 clipped at +-{cut} counts ({n_cut} of {b - a} samples)")
    a, b = ranges[7]
    c[a:b] = FILL
    lines.append(f"zone 7: all {b - a} samples fill")
    a, b = ranges[9]
    keep[b - 800:b - 100] = False
    lines.append("zone 9: 700 samples cut out, a 100-sample stub left at its end")
    return c[keep], keep, lines


def write_fgs(path: Path, times_tt2000: np.ndarray, counts: np.ndarray) -> None:
    """An ELFIN-style FGS file: ``ela_fgs`` (INT4, 3) and ``ela_fgs_time`` (TT2000)."""
    import cdflib

    path.unlink(missing_ok=True)
    w = cdflib.cdfwrite.CDF(str(path), cdf_spec={"Majority": "Row_major"})
    try:
        w.write_globalattrs({"Source_name": {0: "ELA>ELFIN-A (messy copy, magcal workflow)"}})
        w.write_var({"Variable": "ela_fgs_time", "Data_Type": 33, "Num_Elements": 1,
                     "Rec_Vary": True, "Dim_Sizes": [], "Var_Type": "zVariable"},
                    var_attrs={"FILLVAL": [np.int64(-9223372036854775808), "CDF_TIME_TT2000"]},
                    var_data=times_tt2000.astype(np.int64))
        w.write_var({"Variable": "ela_fgs", "Data_Type": 4, "Num_Elements": 1,
                     "Rec_Vary": True, "Dim_Sizes": [3], "Var_Type": "zVariable"},
                    var_attrs={"FILLVAL": [np.int32(FILL), "CDF_INT4"],
                               "DEPEND_0": "ela_fgs_time", "UNITS": "nT"},
                    var_data=counts.astype(np.int32))
    finally:
        w.close()


def main(argv=None) -> int:
    import cdflib

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path, help="folder for the messy copy and its configuration")
    p.add_argument("--data", type=Path, default=DATA, help="folder of the real ELFIN files")
    p.add_argument("--seed", type=int, default=24, help="seed of the spike positions")
    args = p.parse_args(argv)
    src = args.data / FGS
    if not src.is_file():
        p.error(f"real ELFIN data not found: {src}")
    cdf = cdflib.CDF(str(src))
    times = np.asarray(cdf.varget("ela_fgs_time"), dtype=np.int64)
    counts = np.asarray(cdf.varget("ela_fgs")).reshape(-1, 3)
    t_s = (times - times[0]) / 1e9
    messy, keep, lines = make_messy(counts, t_s, np.random.default_rng(args.seed))
    args.out.mkdir(parents=True, exist_ok=True)
    target = args.out / "ela_l1_fgs_20220112_messy.cdf"
    write_fgs(target, times[keep], messy)
    config = args.out / "ELFIN_messy.toml"
    config.write_text(
        "# the ELFIN-A day with faults added (workflows/elfin_messy.py)\n"
        f"[input]\nfiles = [\"{target.resolve()}\"]\n\n"
        "[spin]\nunits = \"counts\"\nreference = \"igrf\"\n"
        f"state = \"{(args.data / STATE).resolve()}\"\n")
    for line in lines:
        print(line)
    print(f"wrote {target} and {config}\nrun: magcal run {config} -o {args.out / 'run'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
