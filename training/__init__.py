"""Training side of sdcnet: the synthetic data generator, the model, training and evaluation."""
