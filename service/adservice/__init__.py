"""activedesign service: the ask/tell server, proposers and representation fusion."""
