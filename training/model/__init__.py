"""SDCNet and its ablation variants as plain ``nn.Module``s, one building block per module."""

from sdcnet.training.model.sdcnet import ModelConfig, SDCNet

__all__ = ["ModelConfig", "SDCNet"]
