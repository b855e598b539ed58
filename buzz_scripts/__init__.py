"""Shipped Buzz scripts, includes, task graphs and examples: `fieldkit.buzz_scripts`."""
