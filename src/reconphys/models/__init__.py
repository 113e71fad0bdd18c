"""Networks: the physics predictor (video → attributes); the 3DGS predictor follows
(docs/design.md#models)."""
