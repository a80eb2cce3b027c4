"""The identification as one function, and what its result says: the written DH model, predictions, validation,
verdict."""
