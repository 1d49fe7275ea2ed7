"""The models stage: object models at real size with physical properties and convex parts."""
