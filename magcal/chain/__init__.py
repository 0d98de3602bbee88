"""The application layer: one configuration, every stage, every product.

* :mod:`magcal.chain.config` - :func:`read_chain_config` (``CHAIN.toml``, checked key by
  key);
* :mod:`magcal.chain.prepare` - input, frames, AC cleaning, model field;
* :mod:`magcal.chain.calibrate` - offsets, corrected data, alignment, discovery;
* :mod:`magcal.chain.spin` - the spinning-spacecraft chain (spin ripple, flipper,
  despin);
* :mod:`magcal.chain.runner` - :func:`run_chain` and the manifest.

The CLI (``magcal run``, ``magcal demo``), the workflows and the tests call
:func:`run_chain`; the stages call the estimators of the stage subpackages.
"""

from magcal.chain.config import ChainConfig, parse_chain_config, read_chain_config
from magcal.chain.runner import ChainResult, run_chain

__all__ = ["ChainConfig", "ChainResult", "parse_chain_config", "read_chain_config",
           "run_chain"]
