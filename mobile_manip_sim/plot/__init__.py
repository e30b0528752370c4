"""`plot`: figures from a run — `run` (the run table and its loaders: a `simulate` CSV or a bag),
`energy` (the energy balance rebuilt from the samples), `figures` (one matplotlib figure each,
the PNGs and index.html); `cli` is the command."""
