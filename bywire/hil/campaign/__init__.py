"""Campaigns: many SIL runs of the shipped scenarios over grids and draws of their parameters, on a
local process pool or a Ray cluster, resumable, with one Parquet row per run (docs/campaigns.md)."""
