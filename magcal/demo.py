"""The main job: ``magcal run`` on the chain configurations shipped with ``data_samples/``.

``data_samples/chain/CHAIN.toml`` simulates a quarter of raw two-sensor daily files
(with a drift and a step in the outboard offset) and runs every geostationary stage;
``data_samples/chain/SPIN.toml`` runs the spinning-spacecraft chain on the Galileo-like
sample. Both are scored against their truth by the chain's own ``truth`` stage.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from magcal.chain import ChainResult, run_chain

#: The demo's chain configurations, relative to data_samples/, and their output folders.
CHAINS = (("chain/CHAIN.toml", "."), ("chain/SPIN.toml", "spinning"))


def run_demo(data: Path, outdir: Path, progress: Callable[[str], None] | None = None
             ) -> list[ChainResult]:
    """Run every demo chain of a ``data_samples`` folder into ``outdir``.

    Returns
    -------
    list of ChainResult
        One per configuration in :data:`CHAINS` (geostationary first).
    """
    return [run_chain(Path(data) / config, Path(outdir) / sub, progress=progress)
            for config, sub in CHAINS]
