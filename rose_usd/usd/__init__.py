"""All OpenUSD authoring of rose_usd: layer names and order, prim paths, atomic layer writes,
the OpenCV <-> USD camera conversion, mesh and physics helpers, schema registration, validation."""
