"""The generic core: roles and capabilities, the run specification, the loop, the
monitor, losses, update rules, the plugin registry, and the small services they use
(errors, progress, atomic files, compiled kernels)."""
