"""The neural baselines of the paper's Table 3, rebuilt small in PyTorch (on the CPU or a GPU).

* :mod:`.rgjw20` — [RGJW20] "Unified Neural Encoding of BTFs": one set encoder and one
  decoder shared by every material; a new material costs one encoder pass per texel
  (:class:`~.rgjw20.RGJW20Method`), optionally followed by latent fine-tuning with the
  decoder frozen (:class:`~.rgjw20.RGJW20FineTunedMethod`, its own row).
* :mod:`.rjgw19` — [RJGW19] "Neural BTF Compression and Interpolation": one autoencoder per
  material, its decoder's weights counted in the material's bytes.
* :mod:`.neumip` — NeuMIP without its neural offset: a neural texture and a small MLP per
  material.

:mod:`._torch` holds what the three share (direction features, the log1p domain, binary16
quantisation, seeding, sample pools, the lazy reconstruction). ``docs/neural-baselines.md``
says what comes from the originals and what we chose. Importing this package imports nothing
from PyTorch; its modules do (the optional ``neural`` extra).
"""
