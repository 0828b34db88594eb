"""Infrastructure the stages share: bundle, providers, trace, outputs, errors, progress, caches, config."""
