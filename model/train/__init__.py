"""Training of the Adaptive O-CNN networks (torch only at training time)."""
