"""The world SemperFi is proven against: constellation, motion, legitimate and attacker signals, noise, truth."""
