"""Camera models, calibration from board images, and calibration file formats."""
