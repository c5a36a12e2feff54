"""DrQ-v2 (facebookresearch/drqv2): data-augmented DDPG from pixels or vectors."""
