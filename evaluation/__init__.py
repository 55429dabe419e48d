"""Evaluation (``sdc-eval``): the yardstick every method is scored with, and the reports
made with it: a dataset split, the real spacecraft, the robustness suite, pose of known
targets, and the model card."""
