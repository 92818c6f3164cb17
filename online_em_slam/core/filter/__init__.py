"""The particle filter over poses: input handling, association, the filter step."""
