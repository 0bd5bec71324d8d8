"""Analysis of finished runs: one loader (``runs``), compact kept run data (``rundata``),
the paper's items (``items``) and ``advisor-jax report`` (``report``)."""
