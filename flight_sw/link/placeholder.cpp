// link component: sources arrive with its issue.
