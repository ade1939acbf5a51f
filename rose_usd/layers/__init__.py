"""Typed readers of the layers stages write, for later stages and for users of a stage."""
