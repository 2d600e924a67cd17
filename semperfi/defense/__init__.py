"""SemperFi's defence: spoofing detection, adversarial peak choice, the Legitimate Signal Retriever (SIC)."""
