"""The plugin: scan -> polygon -> descriptors -> place database -> verified loop closures."""
