// guidance component: sources arrive with its issue.
