"""A simulated camera in the virtual lab: photos of tagged triax blocks, impact jigs, reference
plates and a scale bar, written as image files (the only thing a real camera gives)."""
