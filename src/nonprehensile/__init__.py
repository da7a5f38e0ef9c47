"""nonprehensile."""
