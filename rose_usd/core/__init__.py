"""Math without I/O: rigid transforms, camera models, mesh mass properties, metrics."""
