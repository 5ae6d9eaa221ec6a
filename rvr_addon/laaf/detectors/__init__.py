"""AI-assist detectors H (paper section 5.2): face, saliency, action, speech."""
