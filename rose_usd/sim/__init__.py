"""Newton simulation of a rose stage (imported lazily: warp and newton are heavy)."""
