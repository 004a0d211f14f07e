"""The application services: one per use case, each given only the repositories it uses. The HTTP
API's routes, the console's pages and the command line are adapters over them; they import no
HTTP framework (a contract checks it)."""
