"""``safety-supervisor fleet``: a config's replay over a fleet's archive of bags, one
task per bag, the violations written as a partitioned Parquet dataset
(docs/reference/commands.md, "fleet replay")."""
