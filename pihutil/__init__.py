"""The bottom layer of pih-rflow: small helpers on the standard library that every package (rflow, controllers,
envs, batch, scripts) may import and that import nothing of the project. `atomic`: atomic file and folder writes.
"""
