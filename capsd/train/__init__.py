"""Detector training: data from the simulator, training, labelling, fine-tuning.

Tools: none of it is deployed with the sonar service.
"""
