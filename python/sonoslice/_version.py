"""The package's version, in one place (the dataset writer records it in every manifest)."""
__version__ = "0.1.0"
