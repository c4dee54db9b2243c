"""The bottom layer of pih-rflow: small helpers on the standard library that every package (numerics, rflow,
controllers, envs, batch, scripts) may import and that import nothing of the project. `atomic`: atomic file and folder
writes; `manifest`: the file list of a folder output; `lazy`: a package's public surface re-exported lazily.
"""
