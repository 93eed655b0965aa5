"""Garment replacement in monocular video (Rogge et al. 2014, issue 13): garments, lighting, rendering."""
