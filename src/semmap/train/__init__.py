"""Training the segmentation networks (``semmap train``): data folders, median-frequency class weights,
augmentation and the training loop with checkpoints, logs and the best checkpoint by validation mIoU."""
