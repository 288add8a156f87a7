"""Analysis of recorded runs: loading (Monte Carlo result files, MCAP bags), figures, reports."""
