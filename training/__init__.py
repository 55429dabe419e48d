"""Training side of sdcnet: the synthetic data generator, the model and its training."""
