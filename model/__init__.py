"""The shallow GAN of Fumagalli et al.: networks, losses, metrics, training and evaluation."""
