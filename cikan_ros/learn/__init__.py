"""Learning the time-shift map pi* (SPEC §7-8): labelled data from the conventional TSG, KAN and
MLP models written from their equations, the paper's loss and learning-rate schedule, training,
TPE tuning, model files (safetensors + JSON card) and the learned governor (Algorithm 1).

Modules: ``dataset`` (labels, Parquet, local processes or Dask), ``features`` (float64 features,
z-scoring), ``models`` (B-spline/GRBF/RSWAF KAN layers, MLPs), ``loss``, ``schedule``
(ExpHyperbolicLR), ``train``, ``tune`` (Optuna), ``modelfile`` (save/load, checks),
``governor`` (Algorithm 1), ``bench`` (the ``cikan bench`` section).
"""
