"""Signal conditioning of measured records: steps, noise estimates, input conditioning, the motor observer."""
