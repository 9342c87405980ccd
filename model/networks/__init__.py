"""The networks: generator G, enhancer E, aggregation A, PatchGAN D, VGG19 features, variants."""
