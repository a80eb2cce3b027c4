"""The acquisition plan, decided before anything moves (pure): poses, sweeps, their order, design and predicted
accuracy."""
