"""Training of the physics predictor (docs/design.md#models; docs/training.md).

- :mod:`.config`       the config file + ``key=value`` overrides (sections data, model, objective,
                       optim, train)
- :mod:`.data`         one view's frames + the sample's asset; the (seed, step) → batch order
- :mod:`.objective`    self-supervised photometric loss (self-forcing, truncated), supervised L1
- :mod:`.trainer`      the loop: step, log, checkpoint, resume, export (``reconphys train``)
- :mod:`.checkpoint`   atomic checkpoints with every random state
- :mod:`.distributed`  torchrun / DDP set-up
"""
