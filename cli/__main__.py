from ns2cli import main

main()
