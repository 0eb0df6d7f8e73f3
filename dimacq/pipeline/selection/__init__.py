"""Data selection and diagnostics: perimeter response selection, sensor orientation repair,
jackknife excitation selection with the excitation check, and band selection."""
