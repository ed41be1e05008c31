"""What stands in for the drone: sensor model, motion, BROAD trials, Lab 5 simulator, synth, the emulated board."""
