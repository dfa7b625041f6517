from gsslam.cli import main

main()
