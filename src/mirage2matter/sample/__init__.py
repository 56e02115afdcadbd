"""The bundled sample: a deterministic, rendered capture of a robot workspace with ground truth."""
