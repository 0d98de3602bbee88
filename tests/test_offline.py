"""magcal.offline: astropy's IERS auto-download is off whenever astropy is used, and a
process that never uses astropy does not import it (fresh interpreters: the test
process has astropy loaded already)."""

from __future__ import annotations

import subprocess
import sys


def _run(code: str) -> str:
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, timeout=120)
    return proc.stdout.strip()


def test_configure_before_astropy_is_imported_does_not_import_it_and_still_applies():
    out = _run(
        "import sys\n"
        "from magcal.offline import configure_offline\n"
        "configure_offline(); configure_offline()\n"
        "print('astropy' in sys.modules)\n"
        "import spacepy.time\n"  # spacepy imports astropy, as in the model stages
        "from astropy.utils import iers\n"
        "print(iers.conf.auto_download, iers.conf.auto_max_age)\n"
        "print(sum(type(f).__name__ == '_IersHook' for f in sys.meta_path))\n")
    assert out.split("\n") == ["False", "False None", "0"]


def test_configure_after_astropy_is_imported_applies_at_once():
    out = _run(
        "from astropy.utils import iers\n"
        "iers.conf.auto_download = True\n"
        "from magcal.offline import configure_offline\n"
        "configure_offline()\n"
        "print(iers.conf.auto_download, iers.conf.auto_max_age)\n")
    assert out == "False None"


def test_the_hooked_module_keeps_its_package_data():
    # IERS tables are read through the module's own loader and package path
    out = _run(
        "from magcal.offline import configure_offline\n"
        "configure_offline()\n"
        "from astropy.utils.iers import IERS_B\n"
        "print(len(IERS_B.open()) > 1000)\n")
    assert out == "True"
