"""Show model, show-file loader and formation shapes."""
