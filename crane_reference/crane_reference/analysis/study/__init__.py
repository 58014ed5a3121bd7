"""Constraint-design studies: :mod:`.spec` (what to vary) -> :mod:`.case` (one case's metrics) ->
:mod:`.runner` (local pool or Dask, resumable) -> :mod:`.report` (table, plots, summary)."""
