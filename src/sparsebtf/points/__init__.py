"""BTF data points (paper §3.1): preprocessing, the patch grid and the training point sources.

* :mod:`.preprocessing` — ln(x + offset), BT.601 YUV (:mod:`sparsebtf.colour`), per-angular-image
  standardisation.
* :mod:`.statistics` — what is measured of a BTF first: μ, σ, the bound, the log offset.
* :mod:`.grid` — 4D data points: p×p patches with every light and view, release numbering,
  streaming, seeded sampling.
* :mod:`.sources` — the training set: statistics, the 10% sample, staging on disk.
"""
