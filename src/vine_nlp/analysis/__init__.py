"""Analysis of designs: self-collision (``collision``), manufacturing tolerance (``tolerance``) and
distances to obstacles (``obstacles``).

Pure functions on routings, shapes and results (numpy; CasADi only for Jacobians). No I/O. The submodules are imported
by name (``from vine_nlp.analysis.collision import ...``): the package itself imports none of them, so reading an
archive with obstacles does not load SciPy's optimizers."""
