"""jinja2 templates for the C header, CMake file, example main and the LaTeX report."""
