"""clis_modules: CLIS learning modules (innate, view, place) and the arbiter."""
